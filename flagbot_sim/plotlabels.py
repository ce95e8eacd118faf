"""Labels placed where they overlap nothing: each at the first of a ring of offsets around its point whose box
stays clear of the labels placed before it, of the boxes to avoid (markers, the legend) and inside the axes.

Used by the sweep figures (the letters C, D, E, ... of the paper's points) and the accuracy study (the presets'
names at their runs). Matplotlib only (object-oriented API), no pyplot state.
"""
from __future__ import annotations

import math

#: the directions tried around a point, in order: up-left first (the paper's letters sit there), then the others
ANGLES = (135, 45, -45, -135, 90, -90, 180, 0, 160, 20, -20, -160)


def renderer_of(fig):
    """A renderer for measuring text: the figure's own (Agg) canvas, attached if it has none."""
    if not hasattr(fig.canvas, "get_renderer"):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        FigureCanvasAgg(fig)
    return fig.canvas.get_renderer()


def marker_box(ax, x: float, y: float, size_pt: float):
    """The display box of a marker of ``size_pt`` points centred on data point (x, y)."""
    from matplotlib.transforms import Bbox
    px, py = ax.transData.transform((x, y))
    half = 0.5 * size_pt * ax.figure.dpi / 72.0
    return Bbox([[px - half, py - half], [px + half, py + half]])


def text_box(text, renderer, pad_pt: float = 1.5):
    """The display box of a Text's (or an Annotation's) text alone, with the white backdrop's padding."""
    from matplotlib.text import Annotation, Text
    if isinstance(text, Annotation):
        text.update_positions(renderer)     # an annotation's text is put at its offset only when drawn
    return Text.get_window_extent(text, renderer).padded(pad_pt * text.figure.dpi / 72.0)


def _overlap(a, b) -> float:
    w = min(a.x1, b.x1) - max(a.x0, b.x0)
    h = min(a.y1, b.y1) - max(a.y0, b.y0)
    return w * h if w > 0 and h > 0 else 0.0


def place_labels(ax, items, *, avoid=(), distances=(16.0, 30.0, 46.0), fontsize: float = 8.0, leader: bool = True,
                 **text_kw) -> list:
    """Annotate ``ax`` with ``items`` = [(text, (x, y)), ...] (data coordinates), each label at the first offset
    (``distances`` in points x :data:`ANGLES`) whose box overlaps neither a label placed before it, nor any box in
    ``avoid`` (display Bboxes), and lies inside the axes; failing that, where it overlaps least. A thin leader
    line joins a label to its point. Call it after the figure's layout is final (``fig.draw_without_rendering()``
    for a constrained layout): offsets are in points from the data point. Returns the annotations."""
    fig = ax.figure
    renderer = renderer_of(fig)
    frame = ax.get_window_extent(renderer)
    taken = list(avoid)
    out = []
    style = dict(fontsize=fontsize, color="k", zorder=6,
                 bbox=dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.8))
    style.update(text_kw)
    for text, (x, y) in items:
        best = None
        for r in distances:
            for a in ANGLES:
                dx, dy = r * math.cos(math.radians(a)), r * math.sin(math.radians(a))
                ann = ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset points",
                                  ha="left" if dx > 1 else ("right" if dx < -1 else "center"),
                                  va="bottom" if dy > 1 else ("top" if dy < -1 else "center"),
                                  arrowprops=dict(arrowstyle="-", lw=0.6, color="0.35", shrinkA=0, shrinkB=3)
                                  if leader else None, **style)
                ann.set_in_layout(False)
                box = text_box(ann, renderer)
                outside = box.width * box.height - _overlap(box, frame)
                cost = outside + sum(_overlap(box, t) for t in taken)
                if best is None or cost < best[0]:
                    if best is not None:
                        best[1].remove()
                    best = (cost, ann, box)
                else:
                    ann.remove()
                if cost == 0.0:
                    break
            if best[0] == 0.0:
                break
        taken.append(best[2])
        out.append(best[1])
    return out
