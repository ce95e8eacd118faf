"""Reference and material frames of the edges (compiled: the formulas exist once, here).

Each edge carries a reference frame {d1, d2, t} that is *time-parallel transported*: from one time step to the
next it is rotated by the smallest rotation taking the old tangent to the new one, so it never spins about the
tangent by itself. The material frame is the reference frame turned by the edge's twist angle theta about t:

    m1 = cos(theta) d1 + sin(theta) d2,   m2 = -sin(theta) d1 + cos(theta) d2.

The *reference twist* of a hinge is the angle between the space-parallel transport of the first edge's d1 onto
the second edge and the second edge's own d1 (Bergou et al. 2010). It is tracked continuously (no 2*pi jumps),
because the robot turns its parts through many revolutions.

The scalar helpers (``cross3``, ``transport3``, ``angle3``) are the single implementation of each formula; the
array functions below loop over them and are what the rest of the package calls (hot path and observation
alike). ``NUMBA_DISABLE_JIT=1`` runs the same code as plain Python for debugging. ``material3`` and
``unit_rows`` are plain Python / numpy: nothing compiled calls them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .jit import kernel, stage


# ------------------------------------------------------------------------------------------- scalar formulas
@stage
def cross3(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@stage
def transport3(c0, c1, c2, t0, t1, t2, u0, u1, u2):
    """Rotate u by the minimal rotation taking unit vector c to unit vector t.

    Rodrigues' formula with b = c x t (unnormalised): R u = (c.t) u + b x u + b (b.u) / (1 + c.t); exact for any
    angle below pi and smooth (no branch) as c -> t.
    """
    b0, b1, b2 = cross3(c0, c1, c2, t0, t1, t2)
    c = c0 * t0 + c1 * t1 + c2 * t2
    w0, w1, w2 = cross3(b0, b1, b2, u0, u1, u2)
    bu = (b0 * u0 + b1 * u1 + b2 * u2) / (1.0 + c)
    return c * u0 + w0 + b0 * bu, c * u1 + w1 + b1 * bu, c * u2 + w2 + b2 * bu


@kernel
def angle3(u0, u1, u2, v0, v1, v2, a0, a1, a2):
    """Signed angle from u to v about the axis a (right-handed), in (-pi, pi]."""
    x0, x1, x2 = cross3(u0, u1, u2, v0, v1, v2)
    return math.atan2(x0 * a0 + x1 * a1 + x2 * a2, u0 * v0 + u1 * v1 + u2 * v2)


def material3(d10, d11, d12, d20, d21, d22, theta):
    """Material directors (m1, m2) of a reference frame (d1, d2) turned by the twist angle theta.

    Plain Python: only the observer calls it, once per snapshot (compiled, its first call cost ~0.25 s of
    compiling for nothing measurable per call)."""
    c, s = math.cos(theta), math.sin(theta)
    return (c * d10 + s * d20, c * d11 + s * d21, c * d12 + s * d22,
            -s * d10 + c * d20, -s * d11 + c * d21, -s * d12 + c * d22)


@stage
def unwrap(angle, reference):
    """``angle`` plus the multiple of 2 pi that brings it closest to ``reference``."""
    # np.rint is np.round to 0 decimals (both llvm.rint, half to even); np.round compiles its decimals branch too
    return angle + 2.0 * math.pi * np.rint((reference - angle) / (2.0 * math.pi))


# ------------------------------------------------------------------------------------------- row-wise forms
@kernel
def parallel_transport(u, t1, t2):
    """Row-wise :func:`transport3`: u (n, 3) carried from unit tangents t1 to t2."""
    out = np.empty_like(u)
    for k in range(u.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = transport3(t1[k, 0], t1[k, 1], t1[k, 2], t2[k, 0], t2[k, 1], t2[k, 2],
                                                     u[k, 0], u[k, 1], u[k, 2])
    return out


@kernel
def signed_angle(u, v, axis):
    """Row-wise :func:`angle3`."""
    out = np.empty(u.shape[0])
    for k in range(u.shape[0]):
        out[k] = angle3(u[k, 0], u[k, 1], u[k, 2], v[k, 0], v[k, 1], v[k, 2], axis[k, 0], axis[k, 1], axis[k, 2])
    return out


def unit_rows(v):
    """(v / |v|, |v|) row-wise.

    numpy, not compiled: a model calls it once, the clamp on a few rows per step (compiled, it cost ~0.4 s of a
    first run's compiling); the same operations in the same order as the compiled loop it replaced."""
    n = np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1] + v[:, 2] * v[:, 2])
    return v / n[:, None], n


@kernel
def twist_for_director(d1c, tc, t_new, m_target, theta_old):
    """Twist angles that make each edge's material director m1 equal ``m_target``, given reference frames
    carried from (d1c, tc) to the unit tangents t_new by time-parallel transport; each continuous with
    ``theta_old`` (no 2 pi jumps)."""
    out = np.empty(t_new.shape[0])
    for k in range(t_new.shape[0]):
        t0, t1, t2 = t_new[k, 0], t_new[k, 1], t_new[k, 2]
        p0, p1, p2 = transport3(tc[k, 0], tc[k, 1], tc[k, 2], t0, t1, t2, d1c[k, 0], d1c[k, 1], d1c[k, 2])
        ang = angle3(p0, p1, p2, m_target[k, 0], m_target[k, 1], m_target[k, 2], t0, t1, t2)
        out[k] = unwrap(ang, theta_old[k])
    return out


# ------------------------------------------------------------------------------------------- trial frames
@kernel
def _trial_frames(x, edges, d1c, tc, hinge_edges, sign, ref_prev, t, length, d1, d2, rt):
    for k in range(edges.shape[0]):
        a, b = edges[k, 0], edges[k, 1]
        e0, e1, e2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        le = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        t0, t1, t2 = e0 / le, e1 / le, e2 / le
        length[k] = le
        t[k, 0], t[k, 1], t[k, 2] = t0, t1, t2
        p0, p1, p2 = transport3(tc[k, 0], tc[k, 1], tc[k, 2], t0, t1, t2, d1c[k, 0], d1c[k, 1], d1c[k, 2])
        # re-orthonormalise against round-off drift over millions of steps
        pt = p0 * t0 + p1 * t1 + p2 * t2
        p0, p1, p2 = p0 - pt * t0, p1 - pt * t1, p2 - pt * t2
        pn = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        p0, p1, p2 = p0 / pn, p1 / pn, p2 / pn
        d1[k, 0], d1[k, 1], d1[k, 2] = p0, p1, p2
        d2[k, 0], d2[k, 1], d2[k, 2] = cross3(t0, t1, t2, p0, p1, p2)
    # reference twist: an edge traversed against its direction enters with tangent -t (sign)
    for h in range(hinge_edges.shape[0]):
        ea, eb = hinge_edges[h, 0], hinge_edges[h, 1]
        sa, sb = sign[h, 0], sign[h, 1]
        b0, b1, b2 = sb * t[eb, 0], sb * t[eb, 1], sb * t[eb, 2]
        p0, p1, p2 = transport3(sa * t[ea, 0], sa * t[ea, 1], sa * t[ea, 2], b0, b1, b2,
                                d1[ea, 0], d1[ea, 1], d1[ea, 2])
        ang = angle3(p0, p1, p2, d1[eb, 0], d1[eb, 1], d1[eb, 2], b0, b1, b2)
        rt[h] = unwrap(ang, ref_prev[h])


@dataclass
class TrialFrames:
    """Frames of a trial configuration: tangents, edge lengths, transported reference frames, reference twist."""
    t: np.ndarray
    length: np.ndarray
    d1: np.ndarray
    d2: np.ndarray
    ref_twist: np.ndarray
    t_committed: np.ndarray   # tangents the reference frames were transported from


class EdgeFrames:
    """Committed reference frames of all edges and the hinges' committed reference twist."""

    def __init__(self, t: np.ndarray, d1: np.ndarray, d2: np.ndarray, ref_twist: np.ndarray):
        self.t, self.d1, self.d2, self.ref_twist = t, d1, d2, ref_twist

    @classmethod
    def initial(cls, tangents: np.ndarray, n_hinges: int) -> "EdgeFrames":
        """Reference directors for the straight start: d1 = y for axial edges, x for radial ones.

        With this choice the head's material frame starts as the lab frame (identity orientation). Used once,
        when a model is built; the reference twist is set by the elastic model from these frames.
        """
        t = np.array(tangents, dtype=float)
        cand = np.tile(np.array([0.0, 1.0, 0.0]), (len(t), 1))
        cand[np.abs(t[:, 1]) > 0.5] = np.array([1.0, 0.0, 0.0])
        d1, _ = unit_rows(cand - np.sum(cand * t, axis=1)[:, None] * t)
        d2 = np.cross(t, d1)
        return cls(t, d1, d2, np.zeros(n_hinges))

    @classmethod
    def of(cls, trial: TrialFrames) -> "EdgeFrames":
        """The frames of an accepted trial configuration (takes its arrays: the trial is not used again)."""
        return cls(trial.t, trial.d1, trial.d2, trial.ref_twist)

    def copy(self) -> "EdgeFrames":
        return EdgeFrames(self.t.copy(), self.d1.copy(), self.d2.copy(), self.ref_twist.copy())


def trial_frames(x: np.ndarray, edges: np.ndarray, hinge_edges: np.ndarray, sign: np.ndarray,
                 committed: EdgeFrames) -> TrialFrames:
    """Frames of the configuration with node positions ``x`` (N, 3), carried from the committed frames."""
    ne, nh = edges.shape[0], hinge_edges.shape[0]
    t, length = np.empty((ne, 3)), np.empty(ne)
    d1, d2, rt = np.empty((ne, 3)), np.empty((ne, 3)), np.empty(nh)
    try:
        _trial_frames(x, edges, committed.d1, committed.t, hinge_edges, sign, committed.ref_twist, t, length, d1,
                      d2, rt)
    except ZeroDivisionError:
        # a trial iterate with an edge of zero length or a frame transported onto its tangent has no frames: NaN
        # frames give a non-finite residual, which every solver rejects (a line-search cut, a smaller step)
        for a in (t, length, d1, d2, rt):
            a.fill(np.nan)
    return TrialFrames(t=t, length=length, d1=d1, d2=d2, ref_twist=rt, t_committed=committed.t)
