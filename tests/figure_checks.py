"""What a reader must be able to see in a figure, measured on the drawn figure (display coordinates after layout):
no two labels on top of each other, no curve hidden under another, no two marks on top of each other."""
from __future__ import annotations

import numpy as np
from matplotlib.text import Text
from matplotlib.transforms import Bbox

from flagbot_sim.plotlabels import renderer_of, text_box


def _area(a: Bbox, b: Bbox) -> float:
    w = min(a.x1, b.x1) - max(a.x0, b.x0)
    h = min(a.y1, b.y1) - max(a.y0, b.y0)
    return w * h if w > 0 and h > 0 else 0.0


def label_boxes(fig) -> list[tuple[str, Bbox]]:
    """(what, display box) of every label a reader reads: the figure's texts, each axes' titles, axis labels and
    texts (annotations included), and each legend as one box. Tick labels are left to matplotlib."""
    fig.draw_without_rendering()
    r = renderer_of(fig)
    out = []

    def add(t: Text, what: str):
        if t.get_visible() and t.get_text().strip():
            out.append((f"{what} {t.get_text()!r}", text_box(t, r, pad_pt=0.0)))
    for t in fig.texts:
        add(t, "figure text")
    for leg in fig.legends:
        out.append(("figure legend", leg.get_window_extent(r)))
    for ax in fig.axes:
        for t in (ax.title, ax._left_title, ax._right_title, ax.xaxis.label, ax.yaxis.label, *ax.texts):
            add(t, "text")
        leg = ax.get_legend()
        if leg is not None:
            out.append(("legend", leg.get_window_extent(r)))
    return out


def overlapping(boxes: list[tuple[str, Bbox]], min_area: float = 1.0) -> list[tuple[str, str]]:
    """The pairs of boxes that overlap by more than ``min_area`` square pixels."""
    found = []
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            if _area(boxes[i][1], boxes[j][1]) > min_area:
                found.append((boxes[i][0], boxes[j][0]))
    return found


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of each point of p (m, 2) to each segment a[k] -> b[k]; (m, k)."""
    ab = b - a
    ap = p[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("mkc,kc->mk", ap, ab) / np.maximum(np.einsum("kc,kc->k", ab, ab), 1e-12), 0.0, 1.0)
    d = ap - t[..., None] * ab[None, :, :]
    return np.sqrt(np.einsum("mkc,mkc->mk", d, d))


def _path(ax, line) -> np.ndarray:
    xy = ax.transData.transform(np.column_stack([line.get_xdata(), line.get_ydata()]).astype(float))
    return xy[np.all(np.isfinite(xy), axis=1)]


def _samples(xy: np.ndarray, step: float = 1.0) -> np.ndarray:
    """Points along the polyline every ``step`` pixels."""
    out = [xy[:1]]
    for a, b in zip(xy[:-1], xy[1:]):
        k = max(1, int(np.linalg.norm(b - a) / step))
        out.append(a + (b - a) * (np.arange(1, k + 1) / k)[:, None])
    return np.vstack(out)


def visible_fractions(ax) -> dict:
    """line -> the fraction of its length a reader can see: where the stroke of a line drawn above it (a later
    one, by z-order) covers its own stroke entirely, it is hidden. Lines without a stroke (markers only) and
    straight reference lines of two points are left out."""
    ax.figure.draw_without_rendering()
    px = ax.figure.dpi / 72.0
    lines = [ln for ln in ax.lines if ln.get_visible() and ln.get_linestyle() not in ("None", "", " ")
             and len(ln.get_xdata()) > 2]
    order = sorted(range(len(lines)), key=lambda i: lines[i].get_zorder())       # stable: the drawing order
    out = {}
    for rank, i in enumerate(order):
        me = lines[i]
        pts = _samples(_path(ax, me))
        half = 0.5 * me.get_linewidth() * px
        covered = np.zeros(len(pts), bool)
        for j in order[rank + 1:]:
            top = _path(ax, lines[j])
            if len(top) < 2:
                continue
            d = _segment_distance(pts, top[:-1], top[1:]).min(axis=1)
            covered |= d + half <= 0.5 * lines[j].get_linewidth() * px + 0.5
        out[me] = 1.0 - covered.mean()
    return out


def hidden_curves(fig, min_visible: float = 0.5) -> list[tuple[str, float]]:
    """(label, visible fraction) of every curve of which less than ``min_visible`` can be seen."""
    out = []
    for ax in fig.axes:
        for line, f in visible_fractions(ax).items():
            if f < min_visible:
                out.append((f"{ax.get_title()!r}: {line.get_label()}", round(float(f), 3)))
    return out


def mark_boxes(fig, prefix: str) -> list[tuple[str, Bbox]]:
    """(gid, display box) of every marker whose line's gid starts with ``prefix`` (the figures name their marks)."""
    from flagbot_sim.plotlabels import marker_box
    fig.draw_without_rendering()
    out = []
    for ax in fig.axes:
        for ln in ax.lines:
            gid = ln.get_gid() or ""
            if gid.startswith(prefix) and ln.get_marker() not in ("None", None, ""):
                for x, y in zip(ln.get_xdata(), ln.get_ydata()):
                    out.append((gid, marker_box(ax, x, y, ln.get_markersize())))
    return out


def outside_figure(fig, boxes) -> list[str]:
    """The labels of ``boxes`` that do not lie wholly inside the figure (cut off when saved)."""
    W, H = fig.get_size_inches() * fig.dpi
    return [what for what, b in boxes if b.x0 < -0.5 or b.y0 < -0.5 or b.x1 > W + 0.5 or b.y1 > H + 0.5]
