"""Reference and material frames of the edges, vectorised over all edges.

Each edge carries a reference frame {d1, d2, t} that is *time-parallel transported*: from one time step to the
next it is rotated by the smallest rotation taking the old tangent to the new one, so it never spins about the
tangent by itself. The material frame is the reference frame turned by the edge's twist angle theta about t:

    m1 = cos(theta) d1 + sin(theta) d2,   m2 = -sin(theta) d1 + cos(theta) d2.

The *reference twist* of a hinge is the angle between the space-parallel transport of the first edge's d1 onto
the second edge and the second edge's own d1 (Bergou et al. 2010). It is tracked continuously (no 2*pi jumps),
because the robot turns its parts through many revolutions.
"""
from __future__ import annotations

import numpy as np


def rowdot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (n, 3) arrays (several times faster than np.cross on small batches)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def normalize(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = np.linalg.norm(v, axis=-1)
    return v / n[..., None], n


def parallel_transport(u: np.ndarray, t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """Rotate u by the minimal rotation taking unit vector t1 to unit vector t2 (row-wise).

    Rodrigues' formula with b = t1 x t2 (unnormalised): R u = c u + b x u + b (b.u) / (1 + c), c = t1.t2.
    Exact for any angle below pi and smooth (no branch) as t1 -> t2.
    """
    b = cross(t1, t2)
    c = rowdot(t1, t2)
    return c[..., None] * u + cross(b, u) + b * (rowdot(b, u) / (1.0 + c))[..., None]


def signed_angle(u: np.ndarray, v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Angle from u to v about axis (right-handed), row-wise, in (-pi, pi]."""
    return np.arctan2(rowdot(cross(u, v), axis), rowdot(u, v))


def initial_frames(tangents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference directors for straight-start edges: d1 = y for axial edges, x for the others.

    With this choice the head's material frame starts as the lab frame (identity orientation).
    """
    cand = np.tile(np.array([0.0, 1.0, 0.0]), (len(tangents), 1))
    radial = np.abs(tangents[:, 1]) > 0.5
    cand[radial] = np.array([1.0, 0.0, 0.0])
    d1, _ = normalize(cand - rowdot(cand, tangents)[:, None] * tangents)
    d2 = cross(tangents, d1)
    return d1, d2


def material_frames(d1: np.ndarray, d2: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = np.cos(theta)[:, None]
    s = np.sin(theta)[:, None]
    return c * d1 + s * d2, -s * d1 + c * d2


def unwrap_to(angle: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Add multiples of 2*pi to ``angle`` so that it is the representative closest to ``reference``."""
    return angle + 2.0 * np.pi * np.round((reference - angle) / (2.0 * np.pi))


class EdgeFrames:
    """Committed reference frames of all edges and the hinges' committed reference twist."""

    def __init__(self, tangents: np.ndarray):
        self.t = tangents.copy()
        self.d1, self.d2 = initial_frames(tangents)
        self.ref_twist: np.ndarray | None = None   # set by the elastic model at construction

    def transported(self, t_new: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference frames carried by time-parallel transport to the new tangents (not committed)."""
        d1 = parallel_transport(self.d1, self.t, t_new)
        # re-orthonormalise against round-off drift over millions of steps
        d1 -= rowdot(d1, t_new)[:, None] * t_new
        d1 /= np.linalg.norm(d1, axis=1)[:, None]
        d2 = cross(t_new, d1)
        return d1, d2

    def commit(self, t_new: np.ndarray, d1: np.ndarray, d2: np.ndarray, ref_twist: np.ndarray) -> None:
        self.t = t_new.copy()
        self.d1 = d1.copy()
        self.d2 = d2.copy()
        self.ref_twist = ref_twist.copy()

    @classmethod
    def committed(cls, t, d1, d2, ref_twist) -> "EdgeFrames":
        """Frames made from freshly computed arrays (taken as they are: the caller gives up ownership)."""
        fr = cls.__new__(cls)
        fr.t, fr.d1, fr.d2, fr.ref_twist = t, d1, d2, ref_twist
        return fr

    def copy(self) -> "EdgeFrames":
        other = EdgeFrames.__new__(EdgeFrames)
        other.t, other.d1, other.d2 = self.t.copy(), self.d1.copy(), self.d2.copy()
        other.ref_twist = None if self.ref_twist is None else self.ref_twist.copy()
        return other
