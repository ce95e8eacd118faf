"""Compiled (numba) kernels for the hot path: edge frames, stretching and bend-twist springs.

They compute exactly what :mod:`flagbot_sim.physics.elastic` computes with numpy (tests compare the two to
round-off) but in one pass per spring, scattering straight into the residual vector and the CSC data array
through the slot maps built once by :class:`~flagbot_sim.physics.assembly.SparsePattern`. Measured on design 1
with n = 3 (91 hinges), the numpy evaluation of the bend-twist gradient + Hessian costs ~1.5 ms, mostly the
overhead of ~150 numpy calls on small arrays; these kernels do it in tens of microseconds (README, "Speed").

numba is optional: without it (or with FLAGBOT_KERNELS=numpy) the numpy implementation is used.
"""
from __future__ import annotations

import math
import os

import numpy as np

try:
    if os.environ.get("FLAGBOT_KERNELS", "auto") == "numpy":
        raise ImportError("numpy kernels requested")
    from numba import njit
    AVAILABLE = True
except ImportError:   # pragma: no cover - exercised only without numba
    AVAILABLE = False

    def njit(*args, **kwargs):
        def wrap(f):
            return f
        return wrap if not args or not callable(args[0]) else args[0]


@njit(cache=True, inline="always")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, inline="always")
def _transport(c0, c1, c2, t0, t1, t2, u0, u1, u2):
    """Parallel transport of u from unit tangent c to unit tangent t (frames.parallel_transport)."""
    b0, b1, b2 = _cross(c0, c1, c2, t0, t1, t2)
    c = c0 * t0 + c1 * t1 + c2 * t2
    w0, w1, w2 = _cross(b0, b1, b2, u0, u1, u2)
    bu = (b0 * u0 + b1 * u1 + b2 * u2) / (1.0 + c)
    return c * u0 + w0 + b0 * bu, c * u1 + w1 + b1 * bu, c * u2 + w2 + b2 * bu


@njit(cache=True)
def frames(x, edges, d1c, tc, hinge_edges, sign, ref_prev, t, length, d1, d2, rt):
    """Tangents, lengths, time-parallel transported reference frames and continuous reference twist."""
    for k in range(edges.shape[0]):
        a, b = edges[k, 0], edges[k, 1]
        e0, e1, e2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        le = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        t0, t1, t2 = e0 / le, e1 / le, e2 / le
        length[k] = le
        t[k, 0], t[k, 1], t[k, 2] = t0, t1, t2
        p0, p1, p2 = _transport(tc[k, 0], tc[k, 1], tc[k, 2], t0, t1, t2, d1c[k, 0], d1c[k, 1], d1c[k, 2])
        pt = p0 * t0 + p1 * t1 + p2 * t2
        p0, p1, p2 = p0 - pt * t0, p1 - pt * t1, p2 - pt * t2
        pn = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        p0, p1, p2 = p0 / pn, p1 / pn, p2 / pn
        d1[k, 0], d1[k, 1], d1[k, 2] = p0, p1, p2
        q0, q1, q2 = _cross(t0, t1, t2, p0, p1, p2)
        d2[k, 0], d2[k, 1], d2[k, 2] = q0, q1, q2
    for h in range(hinge_edges.shape[0]):
        ea, eb = hinge_edges[h, 0], hinge_edges[h, 1]
        sa, sb = sign[h, 0], sign[h, 1]
        a0, a1, a2 = sa * t[ea, 0], sa * t[ea, 1], sa * t[ea, 2]
        b0, b1, b2 = sb * t[eb, 0], sb * t[eb, 1], sb * t[eb, 2]
        p0, p1, p2 = _transport(a0, a1, a2, b0, b1, b2, d1[ea, 0], d1[ea, 1], d1[ea, 2])
        v0, v1, v2 = d1[eb, 0], d1[eb, 1], d1[eb, 2]
        x0, x1, x2 = _cross(p0, p1, p2, v0, v1, v2)
        ang = math.atan2(x0 * b0 + x1 * b1 + x2 * b2, p0 * v0 + p1 * v1 + p2 * v2)
        rt[h] = ang + 2.0 * math.pi * np.round((ref_prev[h] - ang) / (2.0 * math.pi))


@njit(cache=True)
def stretch(t, length, rest, EA, dofs, slots, r, data, want_hessian):
    for k in range(t.shape[0]):
        L0 = rest[k]
        le = length[k]
        f = EA[k] * (le / L0 - 1.0)
        for i in range(3):
            r[dofs[k, i]] -= f * t[k, i]
            r[dofs[k, 3 + i]] += f * t[k, i]
        if want_hessian:
            a = EA[k] / L0
            bcoef = EA[k] * (1.0 / L0 - 1.0 / le)
            for i in range(3):
                for j in range(3):
                    tt = t[k, i] * t[k, j]
                    K = a * tt + bcoef * ((1.0 if i == j else 0.0) - tt)
                    data[slots[k, i, j]] += K
                    data[slots[k, 3 + i, 3 + j]] += K
                    data[slots[k, i, 3 + j]] -= K
                    data[slots[k, 3 + i, j]] -= K


@njit(cache=True)
def holonomy(t, tc, length, g, H, want_hessian):
    """Per edge: dOmega/de (3) and d2Omega/de2 (3x3) (see elastic.holonomy_terms).

    With w = t_c x t, c = t_c . t, g_t = -w / (1 + c): P w = w and P (t_c + t) = t_c - c t, so
    P H_t P = (w u'^T + u' w^T) / (2 (1 + c)^2) with u' = t_c - c t, and no matrix products are needed.
    """
    for k in range(t.shape[0]):
        t0, t1, t2 = t[k, 0], t[k, 1], t[k, 2]
        c0, c1, c2 = tc[k, 0], tc[k, 1], tc[k, 2]
        c = c0 * t0 + c1 * t1 + c2 * t2
        w0, w1, w2 = _cross(c0, c1, c2, t0, t1, t2)
        le = length[k]
        gt0, gt1, gt2 = -w0 / (1.0 + c), -w1 / (1.0 + c), -w2 / (1.0 + c)
        g[k, 0], g[k, 1], g[k, 2] = gt0 / le, gt1 / le, gt2 / le
        if not want_hessian:
            continue
        s = 1.0 / (2.0 * (1.0 + c) ** 2)
        up0, up1, up2 = c0 - c * t0, c1 - c * t1, c2 - c * t2
        il2 = 1.0 / (le * le)
        for i in range(3):
            wi = w0 if i == 0 else (w1 if i == 1 else w2)
            ui = up0 if i == 0 else (up1 if i == 1 else up2)
            ti = t0 if i == 0 else (t1 if i == 1 else t2)
            gi = gt0 if i == 0 else (gt1 if i == 1 else gt2)
            for j in range(3):
                wj = w0 if j == 0 else (w1 if j == 1 else w2)
                uj = up0 if j == 0 else (up1 if j == 1 else up2)
                tj = t0 if j == 0 else (t1 if j == 1 else t2)
                gj = gt0 if j == 0 else (gt1 if j == 1 else gt2)
                H[k, i, j] = (s * (wi * uj + ui * wj) - (ti * gj + gi * tj)) * il2


@njit(cache=True)
def bend_twist(x, theta, t, tc, length, d1, d2, rt, hn, he, sign, beta, kappa_bar, tau_bar, k_bend, k_twist,
               dofs, slots, r, data, want_hessian):
    NM = np.array([[-1.0, 0.0], [1.0, -1.0], [0.0, 1.0]])   # node <- edge map
    hg = np.empty((t.shape[0], 3))
    hh = np.empty((t.shape[0], 3, 3))
    holonomy(t, tc, length, hg, hh, want_hessian)
    Hth0 = np.zeros(11)
    Hth1 = np.zeros(11)
    G = np.zeros((3, 11))
    De = np.zeros((3, 3))
    Df = np.zeros((3, 3))
    grad = np.zeros(11)
    hess = np.zeros((11, 11))
    Sx = np.zeros((2, 3, 2, 3))
    Sxt = np.zeros((2, 3, 2))
    V = np.zeros((2, 11))
    S11 = np.ones(11)
    te = np.zeros(3)
    tf = np.zeros(3)
    kb = np.zeros(3)
    tt = np.zeros(3)
    d1t = np.zeros(3)
    d2t = np.zeros(3)
    m1a = np.zeros(3)
    m2a = np.zeros(3)
    m1b = np.zeros(3)
    m2b = np.zeros(3)
    for h in range(hn.shape[0]):
        a, b, c = hn[h, 0], hn[h, 1], hn[h, 2]
        ea, eb = he[h, 0], he[h, 1]
        sa, sb = sign[h, 0], sign[h, 1]
        ne = 0.0
        nf = 0.0
        for i in range(3):
            te[i] = x[b, i] - x[a, i]
            tf[i] = x[c, i] - x[b, i]
            ne += te[i] * te[i]
            nf += tf[i] * tf[i]
        ne = math.sqrt(ne)
        nf = math.sqrt(nf)
        for i in range(3):
            te[i] /= ne
            tf[i] /= nf
        tha = sa * theta[ea] + beta[h]
        thb = sb * theta[eb]
        ca, sa_ = math.cos(tha), math.sin(tha)
        cb, sb_ = math.cos(thb), math.sin(thb)
        for i in range(3):
            d1a, d2a = d1[ea, i], sa * d2[ea, i]
            d1b, d2b = d1[eb, i], sb * d2[eb, i]
            m1a[i] = ca * d1a + sa_ * d2a
            m2a[i] = -sa_ * d1a + ca * d2a
            m1b[i] = cb * d1b + sb_ * d2b
            m2b[i] = -sb_ * d1b + cb * d2b
        chi = 1.0 + te[0] * tf[0] + te[1] * tf[1] + te[2] * tf[2]
        ic = 1.0 / chi
        x0, x1, x2 = _cross(te[0], te[1], te[2], tf[0], tf[1], tf[2])
        kb[0], kb[1], kb[2] = 2.0 * x0 * ic, 2.0 * x1 * ic, 2.0 * x2 * ic
        k1 = 0.0
        k2 = 0.0
        kbm1a = kbm1b = kbm2a = kbm2b = 0.0
        for i in range(3):
            tt[i] = (te[i] + tf[i]) * ic
            d1t[i] = (m1a[i] + m1b[i]) * ic
            d2t[i] = (m2a[i] + m2b[i]) * ic
            k1 += 0.5 * kb[i] * (m2a[i] + m2b[i])
            k2 -= 0.5 * kb[i] * (m1a[i] + m1b[i])
            kbm1a += kb[i] * m1a[i]
            kbm1b += kb[i] * m1b[i]
            kbm2a += kb[i] * m2a[i]
            kbm2b += kb[i] * m2b[i]
        tau = thb - tha + rt[h]
        ine = 1.0 / ne
        inf = 1.0 / nf
        # strain gradients in edge space, rows: kappa1, kappa2, tau
        a0, a1, a2 = _cross(tf[0], tf[1], tf[2], d2t[0], d2t[1], d2t[2])
        b0, b1, b2 = _cross(te[0], te[1], te[2], d2t[0], d2t[1], d2t[2])
        c0, c1, c2 = _cross(tf[0], tf[1], tf[2], d1t[0], d1t[1], d1t[2])
        e0, e1, e2 = _cross(te[0], te[1], te[2], d1t[0], d1t[1], d1t[2])
        De[0, 0], De[0, 1], De[0, 2] = (-k1 * tt[0] + a0) * ine, (-k1 * tt[1] + a1) * ine, (-k1 * tt[2] + a2) * ine
        Df[0, 0], Df[0, 1], Df[0, 2] = (-k1 * tt[0] - b0) * inf, (-k1 * tt[1] - b1) * inf, (-k1 * tt[2] - b2) * inf
        De[1, 0], De[1, 1], De[1, 2] = (-k2 * tt[0] - c0) * ine, (-k2 * tt[1] - c1) * ine, (-k2 * tt[2] - c2) * ine
        Df[1, 0], Df[1, 1], Df[1, 2] = (-k2 * tt[0] + e0) * inf, (-k2 * tt[1] + e1) * inf, (-k2 * tt[2] + e2) * inf
        for i in range(3):
            De[2, i] = 0.5 * kb[i] * ine
            Df[2, i] = 0.5 * kb[i] * inf
        for s in range(3):
            for i in range(3):
                G[s, i] = -De[s, i]
                G[s, 3 + i] = De[s, i] - Df[s, i]
                G[s, 6 + i] = Df[s, i]
        G[0, 9], G[0, 10] = -0.5 * kbm1a, -0.5 * kbm1b
        G[1, 9], G[1, 10] = -0.5 * kbm2a, -0.5 * kbm2b
        G[2, 9], G[2, 10] = -1.0, 1.0
        w1 = k_bend[h] * (k1 - kappa_bar[h, 0])
        w2 = k_bend[h] * (k2 - kappa_bar[h, 1])
        wt = k_twist[h] * (tau - tau_bar[h])
        S11[9], S11[10] = sa, sb
        for j in range(11):
            grad[j] = (w1 * G[0, j] + w2 * G[1, j] + wt * G[2, j]) * S11[j]
        # holonomy of the two edges (change of variables theta -> theta + Omega(x))
        hgA = hg[ea]
        hgB = hg[eb]
        for j in range(11):
            V[0, j] = 0.0
            V[1, j] = 0.0
        for i in range(3):
            V[0, i], V[0, 3 + i] = -sa * hgA[i], sa * hgA[i]
            V[1, 3 + i], V[1, 6 + i] = -sb * hgB[i], sb * hgB[i]
        gA, gB = grad[9], grad[10]
        for j in range(9):
            grad[j] += gA * V[0, j] + gB * V[1, j]
        for j in range(11):
            r[dofs[h, j]] += grad[j]
        if not want_hessian:
            continue
        # ---- Hessian (same algebra as elastic.ElasticModel.hinge_terms)
        K = w1 * k1 + w2 * k2
        Dv0, Dv1, Dv2 = w1 * d2t[0] - w2 * d1t[0], w1 * d2t[1] - w2 * d1t[1], w1 * d2t[2] - w2 * d1t[2]
        A0, A1, A2 = _cross(tf[0], tf[1], tf[2], Dv0, Dv1, Dv2)
        B0, B1, B2 = _cross(te[0], te[1], te[2], Dv0, Dv1, Dv2)
        Av = (A0, A1, A2)
        Bv = (B0, B1, B2)
        Dv = (Dv0, Dv1, Dv2)
        ne2, nf2, nenf = ine * ine, inf * inf, ine * inf
        for i in range(3):
            Mai = w1 * m2a[i] - w2 * m1a[i]
            Mbi = w1 * m2b[i] - w2 * m1b[i]
            for j in range(3):
                Maj = w1 * m2a[j] - w2 * m1a[j]
                Mbj = w1 * m2b[j] - w2 * m1b[j]
                dij = 1.0 if i == j else 0.0
                Kttt = 2.0 * K * tt[i] * tt[j]
                see = (Kttt - (Av[i] * tt[j] + tt[i] * Av[j]) - K * ic * (dij - te[i] * te[j])
                       + 0.25 * (kb[i] * Maj + Mai * kb[j]) - 0.25 * wt * (kb[i] * (te[j] + tt[j])
                                                                              + (te[i] + tt[i]) * kb[j]))
                sff = (Kttt + (Bv[i] * tt[j] + tt[i] * Bv[j]) - K * ic * (dij - tf[i] * tf[j])
                       + 0.25 * (kb[i] * Mbj + Mbi * kb[j]) - 0.25 * wt * (kb[i] * (tf[j] + tt[j])
                                                                              + (tf[i] + tt[i]) * kb[j]))
                # skew([v])_ij = -eps_ijk v_k
                skDv = 0.0
                skte = 0.0
                if i != j:
                    k3 = 3 - i - j
                    sgn = 1.0 if (j - i) % 3 == 1 else -1.0     # eps_{ijk}
                    skDv = -sgn * Dv[k3]
                    skte = -sgn * te[k3]
                sef = (-K * ic * (dij + te[i] * tf[j]) + Kttt - Av[i] * tt[j] + tt[i] * Bv[j] - skDv
                       + wt * (ic * skte - 0.5 * kb[i] * tt[j]))
                Sx[0, i, 0, j] = ne2 * see
                Sx[1, i, 1, j] = nf2 * sff
                Sx[0, i, 1, j] = nenf * sef
                Sx[1, j, 0, i] = nenf * sef
        for jj in range(2):
            if jj == 0:
                s_ = 0.5 * (w1 * kbm1a + w2 * kbm2a)
                wm0, wm1, wm2 = w1 * m1a[0] + w2 * m2a[0], w1 * m1a[1] + w2 * m2a[1], w1 * m1a[2] + w2 * m2a[2]
            else:
                s_ = 0.5 * (w1 * kbm1b + w2 * kbm2b)
                wm0, wm1, wm2 = w1 * m1b[0] + w2 * m2b[0], w1 * m1b[1] + w2 * m2b[1], w1 * m1b[2] + w2 * m2b[2]
            f0, f1, f2 = _cross(tf[0], tf[1], tf[2], wm0, wm1, wm2)
            g0, g1, g2 = _cross(te[0], te[1], te[2], wm0, wm1, wm2)
            Sxt[0, 0, jj], Sxt[0, 1, jj], Sxt[0, 2, jj] = (ine * (s_ * tt[0] - ic * f0), ine * (s_ * tt[1] - ic * f1),
                                                           ine * (s_ * tt[2] - ic * f2))
            Sxt[1, 0, jj], Sxt[1, 1, jj], Sxt[1, 2, jj] = (inf * (s_ * tt[0] + ic * g0), inf * (s_ * tt[1] + ic * g1),
                                                           inf * (s_ * tt[2] + ic * g2))
        for ni in range(3):
            for nj in range(3):
                for i in range(3):
                    for j in range(3):
                        v = 0.0
                        for p in range(2):
                            if NM[ni, p] == 0.0:
                                continue
                            for q in range(2):
                                if NM[nj, q] != 0.0:
                                    v += NM[ni, p] * NM[nj, q] * Sx[p, i, q, j]
                        hess[3 * ni + i, 3 * nj + j] = v
            for i in range(3):
                for jj in range(2):
                    v = NM[ni, 0] * Sxt[0, i, jj] + NM[ni, 1] * Sxt[1, i, jj]
                    hess[3 * ni + i, 9 + jj] = v
                    hess[9 + jj, 3 * ni + i] = v
        hess[9, 9] = 0.5 * (w2 * kbm1a - w1 * kbm2a)
        hess[10, 10] = 0.5 * (w2 * kbm1b - w1 * kbm2b)
        hess[9, 10] = 0.0
        hess[10, 9] = 0.0
        kbh = k_bend[h]
        kth = k_twist[h]
        for i in range(11):
            for j in range(11):
                hess[i, j] = (hess[i, j] + kbh * (G[0, i] * G[0, j] + G[1, i] * G[1, j])
                              + kth * G[2, i] * G[2, j]) * S11[i] * S11[j]
        # change of variables: H <- T^T H T + sum_k g_theta_k d2Omega_k
        for j in range(11):
            Hth0[j] = hess[9, j]
            Hth1[j] = hess[10, j]
        h99, h9a, ha9, haa = hess[9, 9], hess[9, 10], hess[10, 9], hess[10, 10]
        for i in range(11):
            for j in range(11):
                hess[i, j] += (V[0, i] * Hth0[j] + V[1, i] * Hth1[j] + Hth0[i] * V[0, j] + Hth1[i] * V[1, j]
                               + V[0, i] * (h99 * V[0, j] + h9a * V[1, j]) + V[1, i] * (ha9 * V[0, j] + haa * V[1, j]))
        for i in range(3):
            for j in range(3):
                hA = gA * hh[ea, i, j]
                hB = gB * hh[eb, i, j]
                hess[i, j] += hA
                hess[3 + i, 3 + j] += hA + hB
                hess[i, 3 + j] -= hA
                hess[3 + i, j] -= hA
                hess[6 + i, 6 + j] += hB
                hess[3 + i, 6 + j] -= hB
                hess[6 + i, 3 + j] -= hB
        for i in range(11):
            for j in range(11):
                data[slots[h, i, j]] += hess[i, j]


# ---------------------------------------------------------------------------------------------- banded LU
@njit(cache=True)
def gbtrf(ab, kl, ku, ipiv):
    """LU with partial pivoting of a band matrix in LAPACK storage (A[i, j] = ab[kl + ku + i - j, j]).

    The algorithm of LAPACK's dgbtf2; rows 0..kl-1 of ab are fill-in space. Returns 0, or j + 1 if U[j, j] = 0.
    """
    n = ab.shape[1]
    kv = ku + kl
    for j in range(kv, n):                      # fill-in space above the band starts at zero
        for i in range(kv - j, kl):
            if i >= 0:
                ab[i, j] = 0.0
    for j in range(n):
        for i in range(kl):
            ab[i, j] = 0.0 if j >= kv - i else ab[i, j]
    info = 0
    ju = 0
    for j in range(n):
        km = min(kl, n - 1 - j)
        jp = 0
        best = abs(ab[kv, j])
        for i in range(1, km + 1):
            v = abs(ab[kv + i, j])
            if v > best:
                best, jp = v, i
        ipiv[j] = j + jp
        if ab[kv + jp, j] == 0.0:
            if info == 0:
                info = j + 1
            continue
        ju = max(ju, min(j + ku + jp, n - 1))
        if jp != 0:                               # swap rows j and j + jp over columns j..ju
            for c in range(j, ju + 1):
                r1 = kv + j - c
                r2 = kv + j + jp - c
                tmp = ab[r1, c]
                ab[r1, c] = ab[r2, c]
                ab[r2, c] = tmp
        piv = ab[kv, j]
        for i in range(1, km + 1):
            ab[kv + i, j] /= piv
        for c in range(j + 1, ju + 1):
            a_jc = ab[kv + j - c, c]
            if a_jc != 0.0:
                for i in range(1, km + 1):
                    ab[kv + j + i - c, c] -= ab[kv + i, j] * a_jc
    return info


@njit(cache=True)
def gbtrs(ab, kl, ku, ipiv, b):
    """Solve A x = b in place for the columns of b (n, k), with A factored by gbtrf."""
    n = ab.shape[1]
    kv = ku + kl
    nr = b.shape[1]
    for j in range(n):                            # L: row interchanges and unit lower band
        p = ipiv[j]
        if p != j:
            for c in range(nr):
                tmp = b[j, c]
                b[j, c] = b[p, c]
                b[p, c] = tmp
        km = min(kl, n - 1 - j)
        for i in range(1, km + 1):
            l = ab[kv + i, j]
            for c in range(nr):
                b[j + i, c] -= l * b[j, c]
    for j in range(n - 1, -1, -1):                # U: upper band of width kv
        d = ab[kv, j]
        for c in range(nr):
            b[j, c] /= d
        lo = max(0, j - kv)
        for i in range(lo, j):
            u = ab[kv + i - j, j]
            for c in range(nr):
                b[i, c] -= u * b[j, c]


@njit(cache=True)
def arrow_factor(buf, ab_off, ab_rows, ab_cols, kl, ku, B_off, C_off, cc_ptr, cc, cr_ptr, cr, D_off, nc, ipiv_all,
                 ipiv_off, Y_all, Y_off):
    """Factor every chain block, form Y_i = A_i^-1 B_i and the Schur complement S = D - sum C_i Y_i in place."""
    for i in range(ab_off.shape[0]):
        ldab, m = ab_rows[i], ab_cols[i]
        ab = buf[ab_off[i]:ab_off[i] + ldab * m].reshape((m, ldab)).T      # Fortran-ordered view
        ipiv = ipiv_all[ipiv_off[i]:ipiv_off[i] + m]
        info = gbtrf(ab, kl[i], ku[i], ipiv)
        if info != 0:
            return i + 1
        ncc = cc_ptr[i + 1] - cc_ptr[i]
        ncr = cr_ptr[i + 1] - cr_ptr[i]
        Y = Y_all[Y_off[i]:Y_off[i] + m * ncc].reshape((m, ncc))
        B = buf[B_off[i]:B_off[i] + m * ncc].reshape((m, ncc))
        Y[:, :] = B
        gbtrs(ab, kl[i], ku[i], ipiv, Y)
        C = buf[C_off[i]:C_off[i] + ncr * m].reshape((ncr, m))
        for a in range(ncr):
            row = cr[cr_ptr[i] + a]
            for bcol in range(ncc):
                col = cc[cc_ptr[i] + bcol]
                acc = 0.0
                for k in range(m):
                    acc += C[a, k] * Y[k, bcol]
                buf[D_off + row * nc + col] -= acc
    return 0


# ---------------------------------------------------------------------------------------------- RFT
@njit(cache=True)
def rft(x, x_old, dt, k, a, b, vor, eta_t, eta_p, F, J_k, J_b, want_jacobian):
    """Resistive-force theory on the flagellum nodes (see effects.RFTDrag): forces and dF/dx_k, dF/dx_b."""
    de = eta_t - eta_p
    for n in range(k.shape[0]):
        kk, aa, bb = k[n], a[n], b[n]
        v0 = (x[kk, 0] - x_old[kk, 0]) / dt
        v1 = (x[kk, 1] - x_old[kk, 1]) / dt
        v2 = (x[kk, 2] - x_old[kk, 2]) / dt
        c0, c1, c2 = x[bb, 0] - x[aa, 0], x[bb, 1] - x[aa, 1], x[bb, 2] - x[aa, 2]
        chord = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        t0, t1, t2 = c0 / chord, c1 / chord, c2 / chord
        vt = v0 * t0 + v1 * t1 + v2 * t2
        l = vor[n]
        F[n, 0] = -l * (eta_p * v0 + de * vt * t0)
        F[n, 1] = -l * (eta_p * v1 + de * vt * t1)
        F[n, 2] = -l * (eta_p * v2 + de * vt * t2)
        if not want_jacobian:
            continue
        t = (t0, t1, t2)
        v = (v0, v1, v2)
        # dF/dt = -l de (vt I + t v^T); dt/dx_b = (I - t t^T) / chord
        for i in range(3):
            for j in range(3):
                dij = 1.0 if i == j else 0.0
                J_k[n, i, j] = -(l / dt) * (eta_p * dij + de * t[i] * t[j])
                acc = 0.0
                for m in range(3):
                    dft = -l * de * (vt * (1.0 if i == m else 0.0) + t[i] * v[m])
                    acc += dft * ((1.0 if m == j else 0.0) - t[m] * t[j])
                J_b[n, i, j] = acc / chord


# ---------------------------------------------------------------------------------------------- predictor
@njit(cache=True)
def predict_cylindrical(x, v, v_prev, h1, h2, c1, c0, second, i0, i1, i2, out):
    """Second-order extrapolation of node positions in cylindrical coordinates about the robot axis (see
    Stepper.predict). ``out`` holds the Cartesian prediction on entry (kept for nodes on the axis)."""
    if i0 != i2:
        a0, a1, a2 = x[i2, 0] - x[i0, 0], x[i2, 1] - x[i0, 1], x[i2, 2] - x[i0, 2]
        na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        a0, a1, a2 = a0 / na, a1 / na, a2 / na
    else:
        a0, a1, a2 = 1.0, 0.0, 0.0
    cn0, cn1, cn2 = out[i1, 0], out[i1, 1], out[i1, 2]          # the centre, predicted on the axis
    # the centre at the three times
    C = np.empty((3, 3))
    for i in range(3):
        C[0, i] = x[i1, i]
        C[1, i] = C[0, i] - h1 * v[i1, i]
        C[2, i] = C[1, i] - h2 * v_prev[i1, i] if second else C[1, i]
    P = np.empty((3, 3))
    S = np.empty(3)
    R = np.empty((3, 3))
    rn = np.empty(3)
    for k in range(x.shape[0]):
        for i in range(3):
            P[0, i] = x[k, i]
            P[1, i] = P[0, i] - h1 * v[k, i]
            P[2, i] = P[1, i] - h2 * v_prev[k, i] if second else P[1, i]
        ok = True
        for j in range(3):
            p0, p1, p2 = P[j, 0] - C[j, 0], P[j, 1] - C[j, 1], P[j, 2] - C[j, 2]
            s = p0 * a0 + p1 * a1 + p2 * a2
            S[j] = s
            R[j, 0], R[j, 1], R[j, 2] = p0 - s * a0, p1 - s * a1, p2 - s * a2
            rn[j] = math.sqrt(R[j, 0] ** 2 + R[j, 1] ** 2 + R[j, 2] ** 2)
            if rn[j] <= 1e-9:
                ok = False
        if not ok:
            continue
        # turn from configuration j+1 to j about the axis
        x0, x1, x2 = _cross(R[1, 0], R[1, 1], R[1, 2], R[0, 0], R[0, 1], R[0, 2])
        dphi = math.atan2(x0 * a0 + x1 * a1 + x2 * a2, R[1, 0] * R[0, 0] + R[1, 1] * R[0, 1] + R[1, 2] * R[0, 2]) / h1
        ds = (S[0] - S[1]) / h1
        dr = (rn[0] - rn[1]) / h1
        if second:
            y0, y1, y2 = _cross(R[2, 0], R[2, 1], R[2, 2], R[1, 0], R[1, 1], R[1, 2])
            dphi0 = math.atan2(y0 * a0 + y1 * a1 + y2 * a2,
                               R[2, 0] * R[1, 0] + R[2, 1] * R[1, 1] + R[2, 2] * R[1, 2]) / h2
            ds0 = (S[1] - S[2]) / h2
            dr0 = (rn[1] - rn[2]) / h2
        else:
            dphi0 = ds0 = dr0 = 0.0
        s_new = S[0] + c1 * ds + c0 * ds0
        r_new = rn[0] + c1 * dr + c0 * dr0
        phi = c1 * dphi + c0 * dphi0
        u0, u1, u2 = R[0, 0] / rn[0], R[0, 1] / rn[0], R[0, 2] / rn[0]
        w0, w1, w2 = _cross(a0, a1, a2, u0, u1, u2)
        cp, sp = math.cos(phi), math.sin(phi)
        out[k, 0] = cn0 + s_new * a0 + r_new * (cp * u0 + sp * w0)
        out[k, 1] = cn1 + s_new * a1 + r_new * (cp * u1 + sp * w1)
        out[k, 2] = cn2 + s_new * a2 + r_new * (cp * u2 + sp * w2)


# ---------------------------------------------------------------------------------------------- arrow solve
@njit(cache=True)
def getrf(A, piv):
    """Dense LU with partial pivoting in place (row interchanges in piv). Returns 0, or j + 1 if singular."""
    n = A.shape[0]
    for j in range(n):
        p = j
        best = abs(A[j, j])
        for i in range(j + 1, n):
            if abs(A[i, j]) > best:
                best, p = abs(A[i, j]), i
        piv[j] = p
        if best == 0.0:
            return j + 1
        if p != j:
            for c in range(n):
                tmp = A[j, c]
                A[j, c] = A[p, c]
                A[p, c] = tmp
        d = A[j, j]
        for i in range(j + 1, n):
            A[i, j] /= d
            l = A[i, j]
            if l != 0.0:
                for c in range(j + 1, n):
                    A[i, c] -= l * A[j, c]
    return 0


@njit(cache=True)
def getrs(A, piv, b):
    n = A.shape[0]
    for j in range(n):
        p = piv[j]
        if p != j:
            tmp = b[j]
            b[j] = b[p]
            b[p] = tmp
    for i in range(n):
        acc = b[i]
        for k in range(i):
            acc -= A[i, k] * b[k]
        b[i] = acc
    for i in range(n - 1, -1, -1):
        acc = b[i]
        for k in range(i + 1, n):
            acc -= A[i, k] * b[k]
        b[i] = acc / A[i, i]


@njit(cache=True)
def arrow_solve(buf, ab_off, ab_rows, ab_cols, kl, ku, C_off, cc_ptr, cc, cr_ptr, cr, D_off, nc, ipiv_all,
                ipiv_off, Y_all, Y_off, core_piv, chain_dofs, chain_ptr, core_dofs, b, x):
    """Solve with the factors of arrow_factor (+ getrf of the core Schur complement, in buf)."""
    rhs = np.empty(nc)
    for k in range(nc):
        rhs[k] = b[core_dofs[k]]
    zmax = 0
    for i in range(ab_off.shape[0]):
        zmax = max(zmax, chain_ptr[i + 1] - chain_ptr[i])
    z = np.empty((zmax, 1))
    for i in range(ab_off.shape[0]):
        ldab, m = ab_rows[i], ab_cols[i]
        ab = buf[ab_off[i]:ab_off[i] + ldab * m].reshape((m, ldab)).T
        ipiv = ipiv_all[ipiv_off[i]:ipiv_off[i] + m]
        zi = z[:m]
        for k in range(m):
            zi[k, 0] = b[chain_dofs[chain_ptr[i] + k]]
        gbtrs(ab, kl[i], ku[i], ipiv, zi)
        ncr = cr_ptr[i + 1] - cr_ptr[i]
        C = buf[C_off[i]:C_off[i] + ncr * m].reshape((ncr, m))
        for a in range(ncr):
            acc = 0.0
            for k in range(m):
                acc += C[a, k] * zi[k, 0]
            rhs[cr[cr_ptr[i] + a]] -= acc
        for k in range(m):
            x[chain_dofs[chain_ptr[i] + k]] = zi[k, 0]
    S = buf[D_off:D_off + nc * nc].reshape((nc, nc))
    getrs(S, core_piv, rhs)
    for k in range(nc):
        x[core_dofs[k]] = rhs[k]
    for i in range(ab_off.shape[0]):
        m = ab_cols[i]
        ncc = cc_ptr[i + 1] - cc_ptr[i]
        Y = Y_all[Y_off[i]:Y_off[i] + m * ncc].reshape((m, ncc))
        for k in range(m):
            acc = 0.0
            for c in range(ncc):
                acc += Y[k, c] * rhs[cc[cc_ptr[i] + c]]
            x[chain_dofs[chain_ptr[i] + k]] -= acc


# ---------------------------------------------------------------------------------------------- clamp
@njit(cache=True)
def clamp_twist(d1c, tc, t_new, m_target, theta_old, out):
    """Twist angles giving material director m_target on edges whose reference frames are carried from (d1c, tc)
    to t_new by time-parallel transport; each continuous with theta_old."""
    for k in range(t_new.shape[0]):
        t0, t1, t2 = t_new[k, 0], t_new[k, 1], t_new[k, 2]
        p0, p1, p2 = _transport(tc[k, 0], tc[k, 1], tc[k, 2], t0, t1, t2, d1c[k, 0], d1c[k, 1], d1c[k, 2])
        m0, m1, m2 = m_target[k, 0], m_target[k, 1], m_target[k, 2]
        x0, x1, x2 = _cross(p0, p1, p2, m0, m1, m2)
        ang = math.atan2(x0 * t0 + x1 * t1 + x2 * t2, p0 * m0 + p1 * m1 + p2 * m2)
        out[k] = ang + 2.0 * math.pi * np.round((theta_old[k] - ang) / (2.0 * math.pi))
