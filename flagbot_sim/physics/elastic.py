"""Elastic energies of the rod network: stretching, bending and twisting, compiled, over all springs at once.

Paper equations: stretch Eq. (stretch, stretchingEnergy), curvature binormal Eq. (curvature), material curvatures
Eq. (BendingCurvature1/2), bending energy Eq. (bendingEnergy), twist and twisting energy Eq. (twistingEnergy).
Derivative formulas follow Bergou et al. (2008, 2010) and Jawed et al. (2018, "A primer on the kinematics of
discrete elastic rods"), written for a hinge whose edges may run against the traversal direction (sign s): such
an edge enters with tangent -t, reference frame (d1, -d2) and twist angle -theta.

The bend-twist springs go through small compiled stages, each one formula of the energy's chain rule and one
loop over all hinges at once (the arrays of one stage are the input of the next):

    _hinge_geometry     edge vectors, material frames, curvature binormal -> strains (kappa1, kappa2, tau)
    _hinge_weights      w_i = k_i (s_i - s_i_bar), the natural twist shifted by the motor
    _strain_gradients   d(strain)/d(local DOFs), local DOFs [x_a, x_b, x_c, theta_ea, theta_eb]
    _gradients          sum_i w_i d(s_i)
    _hessians           sum_i k_i d(s_i) d(s_i)^T + sum_i w_i d2(s_i)
    _edge_holonomy      the reference frame's spin under transport (exactness away from the committed frames)
    _change_variables   theta -> theta + Omega(x) applied to gradient and Hessian
    _scatter            into the residual vector and the CSC data array through slots built once

and ``_bend_twist`` runs them. Energy, gradient and Hessian come from the same stages, so the finite-difference
tests check the code that runs.
"""
from __future__ import annotations

import math
import numpy as np
from numba import njit

from .frames import EdgeFrames, TrialFrames, cross3, trial_frames
from .network import RodNetwork

# ----------------------------------------------------------------------------------------------- stretching
@njit(cache=True)
def _stretch(t, length, rest, EA, dofs, slots, r, J, want_hessian):
    """E = 1/2 EA (l/l0 - 1)^2 l0 per edge: gradient into r, Hessian into J."""
    for k in range(t.shape[0]):
        L0 = rest[k]
        f = EA[k] * (length[k] / L0 - 1.0)
        for i in range(3):
            r[dofs[k, i]] -= f * t[k, i]
            r[dofs[k, 3 + i]] += f * t[k, i]
        if want_hessian:
            a = EA[k] / L0
            b = EA[k] * (1.0 / L0 - 1.0 / length[k])
            for i in range(3):
                for j in range(3):
                    tt = t[k, i] * t[k, j]
                    K = a * tt + b * ((1.0 if i == j else 0.0) - tt)
                    J[slots[k, i, j]] += K
                    J[slots[k, 3 + i, 3 + j]] += K
                    J[slots[k, i, 3 + j]] -= K
                    J[slots[k, 3 + i, j]] -= K


@njit(cache=True)
def _stretch_energy(length, rest, EA):
    E = 0.0
    for k in range(length.shape[0]):
        eps = length[k] / rest[k] - 1.0
        E += 0.5 * EA[k] * eps * eps * rest[k]
    return E


# ----------------------------------------------------------------------------------------------- hinge stages
# Each stage is one loop over all hinges with its formula written on local scalars; the stages hand arrays over
# all hinges to each other. (A per-hinge function taking the spring arrays was 6x slower: numba passes every
# array struct by value at every call.)

@njit(cache=True)
def _hinge_geometry(x, theta, d1, d2, rt, nodes, edges, sign, beta, V, S):
    """Kinematics and strains of every hinge (paper Eqs. curvature, BendingCurvature1/2, twistingEnergy).

    V[h] (7, 3): unit edge tangents te, tf, material directors m1a, m2a, m1b, m2b, curvature binormal kb.
    S[h] (6): edge lengths ne, nf, chi = 1 + te.tf, kappa1, kappa2, and the twist tau without natural twist."""
    for h in range(nodes.shape[0]):
        a, b, c = nodes[h, 0], nodes[h, 1], nodes[h, 2]
        ea, eb = edges[h, 0], edges[h, 1]
        sa, sb = sign[h, 0], sign[h, 1]
        e0, e1, e2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        f0, f1, f2 = x[c, 0] - x[b, 0], x[c, 1] - x[b, 1], x[c, 2] - x[b, 2]
        ne = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        nf = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
        e0, e1, e2 = e0 / ne, e1 / ne, e2 / ne
        f0, f1, f2 = f0 / nf, f1 / nf, f2 / nf
        tha = sa * theta[ea] + beta[h]
        thb = sb * theta[eb]
        ca, sna = math.cos(tha), math.sin(tha)
        cb, snb = math.cos(thb), math.sin(thb)
        chi = 1.0 + e0 * f0 + e1 * f1 + e2 * f2
        kb0 = 2.0 * (e1 * f2 - e2 * f1) / chi
        kb1 = 2.0 * (e2 * f0 - e0 * f2) / chi
        kb2 = 2.0 * (e0 * f1 - e1 * f0) / chi
        Vh = V[h]
        Vh[0, 0], Vh[0, 1], Vh[0, 2] = e0, e1, e2
        Vh[1, 0], Vh[1, 1], Vh[1, 2] = f0, f1, f2
        Vh[6, 0], Vh[6, 1], Vh[6, 2] = kb0, kb1, kb2
        k1 = 0.0
        k2 = 0.0
        for i in range(3):
            # an edge traversed against its direction enters with the reference frame (d1, -d2)
            m1a = ca * d1[ea, i] + sna * sa * d2[ea, i]
            m2a = -sna * d1[ea, i] + ca * sa * d2[ea, i]
            m1b = cb * d1[eb, i] + snb * sb * d2[eb, i]
            m2b = -snb * d1[eb, i] + cb * sb * d2[eb, i]
            Vh[2, i], Vh[3, i], Vh[4, i], Vh[5, i] = m1a, m2a, m1b, m2b
            kbi = Vh[6, i]
            k1 += 0.5 * kbi * (m2a + m2b)
            k2 -= 0.5 * kbi * (m1a + m1b)
        Sh = S[h]
        Sh[0], Sh[1], Sh[2], Sh[3], Sh[4], Sh[5] = ne, nf, chi, k1, k2, thb - tha + rt[h]


@njit(cache=True)
def _hinge_weights(S, kappa_bar, tau_bar, twist_hinge, twist_offset, k_bend, k_twist, W):
    """W[h] = (w1, w2, wt) = k_i (s_i - s_i_bar): the energy's derivative w.r.t. each strain. The natural twist
    of hinge ``twist_hinge`` is shifted by ``twist_offset`` (the motor, paper Eq. SpecifyTheta)."""
    for h in range(S.shape[0]):
        tb = tau_bar[h] + (twist_offset if h == twist_hinge else 0.0)
        W[h, 0] = k_bend[h] * (S[h, 3] - kappa_bar[h, 0])
        W[h, 1] = k_bend[h] * (S[h, 4] - kappa_bar[h, 1])
        W[h, 2] = k_twist[h] * (S[h, 5] - tb)


@njit(cache=True)
def _hinge_energy(S, kappa_bar, tau_bar, twist_hinge, twist_offset, k_bend, k_twist):
    E = 0.0
    for h in range(S.shape[0]):
        tb = tau_bar[h] + (twist_offset if h == twist_hinge else 0.0)
        dk1, dk2, dt = S[h, 3] - kappa_bar[h, 0], S[h, 4] - kappa_bar[h, 1], S[h, 5] - tb
        E += 0.5 * k_bend[h] * (dk1 * dk1 + dk2 * dk2) + 0.5 * k_twist[h] * dt * dt
    return E


@njit(cache=True)
def _strain_gradients(V, S, G):
    """G[h] (3, 11): gradients of kappa1, kappa2, tau w.r.t. [x_a, x_b, x_c, theta_a, theta_b] (edges unsigned).

    In edge space (e = x_b - x_a, f = x_c - x_b), with tt = (te + tf)/chi, d1~ = (m1a + m1b)/chi,
    d2~ = (m2a + m2b)/chi: dk1/de = (-k1 tt + tf x d2~)/|e|, dk1/df = (-k1 tt - te x d2~)/|f|,
    dk2/de = (-k2 tt - tf x d1~)/|e|, dk2/df = (-k2 tt + te x d1~)/|f|, dtau/de = kb/(2|e|), dtau/df = kb/(2|f|)
    (the last through the reference twist), mapped to nodes by x_a = -e, x_b = e - f, x_c = f."""
    for h in range(V.shape[0]):
        Vh, Gh = V[h], G[h]
        ne, nf, chi, k1, k2 = S[h, 0], S[h, 1], S[h, 2], S[h, 3], S[h, 4]
        ic, ine, inf = 1.0 / chi, 1.0 / ne, 1.0 / nf
        te0, te1, te2 = Vh[0, 0], Vh[0, 1], Vh[0, 2]
        tf0, tf1, tf2 = Vh[1, 0], Vh[1, 1], Vh[1, 2]
        d10, d11, d12 = (Vh[2, 0] + Vh[4, 0]) * ic, (Vh[2, 1] + Vh[4, 1]) * ic, (Vh[2, 2] + Vh[4, 2]) * ic
        d20, d21, d22 = (Vh[3, 0] + Vh[5, 0]) * ic, (Vh[3, 1] + Vh[5, 1]) * ic, (Vh[3, 2] + Vh[5, 2]) * ic
        A = cross3(tf0, tf1, tf2, d20, d21, d22)
        B = cross3(te0, te1, te2, d20, d21, d22)
        C = cross3(tf0, tf1, tf2, d10, d11, d12)
        E = cross3(te0, te1, te2, d10, d11, d12)
        for i in range(3):
            tti = (Vh[0, i] + Vh[1, i]) * ic
            de0 = (-k1 * tti + A[i]) * ine
            df0 = (-k1 * tti - B[i]) * inf
            de1 = (-k2 * tti - C[i]) * ine
            df1 = (-k2 * tti + E[i]) * inf
            de2 = 0.5 * Vh[6, i] * ine
            df2 = 0.5 * Vh[6, i] * inf
            Gh[0, i], Gh[0, 3 + i], Gh[0, 6 + i] = -de0, de0 - df0, df0
            Gh[1, i], Gh[1, 3 + i], Gh[1, 6 + i] = -de1, de1 - df1, df1
            Gh[2, i], Gh[2, 3 + i], Gh[2, 6 + i] = -de2, de2 - df2, df2
        kbm1a = Vh[6, 0] * Vh[2, 0] + Vh[6, 1] * Vh[2, 1] + Vh[6, 2] * Vh[2, 2]
        kbm2a = Vh[6, 0] * Vh[3, 0] + Vh[6, 1] * Vh[3, 1] + Vh[6, 2] * Vh[3, 2]
        kbm1b = Vh[6, 0] * Vh[4, 0] + Vh[6, 1] * Vh[4, 1] + Vh[6, 2] * Vh[4, 2]
        kbm2b = Vh[6, 0] * Vh[5, 0] + Vh[6, 1] * Vh[5, 1] + Vh[6, 2] * Vh[5, 2]
        Gh[0, 9], Gh[0, 10] = -0.5 * kbm1a, -0.5 * kbm1b
        Gh[1, 9], Gh[1, 10] = -0.5 * kbm2a, -0.5 * kbm2b
        Gh[2, 9], Gh[2, 10] = -1.0, 1.0


@njit(cache=True)
def _gradients(G, W, sign, grad):
    """grad[h] (11) = sum_i w_i grad(s_i), with the twist DOFs of reversed edges signed."""
    for h in range(G.shape[0]):
        w1, w2, wt = W[h, 0], W[h, 1], W[h, 2]
        for j in range(9):
            grad[h, j] = w1 * G[h, 0, j] + w2 * G[h, 1, j] + wt * G[h, 2, j]
        for j in (9, 10):
            grad[h, j] = (w1 * G[h, 0, j] + w2 * G[h, 1, j] + wt * G[h, 2, j]) * sign[h, j - 9]


@njit(cache=True)
def _skew(v0, v1, v2, i, j):
    """Entry (i, j) of [v]x (the matrix with [v]x u = v x u): -eps_ijk v_k."""
    if i == j:
        return 0.0
    k = 3 - i - j
    vk = v0 if k == 0 else (v1 if k == 1 else v2)
    return -vk if (j - i) % 3 == 1 else vk


@njit(cache=True)
def _hessians(V, S, W, G, sign, k_bend, k_twist, Hs):
    """Hs[h] (11, 11): the energy's Hessian w.r.t. the hinge's local DOFs, sum_i k_i grad(s_i) grad(s_i)^T +
    sum_i w_i d2(s_i), twist DOFs of reversed edges signed.

    The weighted curvature Hessians are linear in the frame vectors, so they are formed directly from
    K = w1 k1 + w2 k2 and Dv = w1 d2~ - w2 d1~ instead of one Hessian per strain (Bergou et al. 2010; Jawed et
    al. 2018), in edge space (blocks S_ee, S_ff, S_ef) and then mapped to nodes by x_a = -e, x_b = e - f, x_c = f."""
    See = np.empty((3, 3))
    Sff = np.empty((3, 3))
    Sef = np.empty((3, 3))
    for h in range(V.shape[0]):
        Vh, Hh, Gh = V[h], Hs[h], G[h]
        ne, nf, chi, k1, k2 = S[h, 0], S[h, 1], S[h, 2], S[h, 3], S[h, 4]
        w1, w2, wt = W[h, 0], W[h, 1], W[h, 2]
        ic, ine, inf = 1.0 / chi, 1.0 / ne, 1.0 / nf
        te0, te1, te2 = Vh[0, 0], Vh[0, 1], Vh[0, 2]
        tf0, tf1, tf2 = Vh[1, 0], Vh[1, 1], Vh[1, 2]
        tt0, tt1, tt2 = (te0 + tf0) * ic, (te1 + tf1) * ic, (te2 + tf2) * ic
        Dv0 = (w1 * (Vh[3, 0] + Vh[5, 0]) - w2 * (Vh[2, 0] + Vh[4, 0])) * ic
        Dv1 = (w1 * (Vh[3, 1] + Vh[5, 1]) - w2 * (Vh[2, 1] + Vh[4, 1])) * ic
        Dv2 = (w1 * (Vh[3, 2] + Vh[5, 2]) - w2 * (Vh[2, 2] + Vh[4, 2])) * ic
        A0, A1, A2 = cross3(tf0, tf1, tf2, Dv0, Dv1, Dv2)
        B0, B1, B2 = cross3(te0, te1, te2, Dv0, Dv1, Dv2)
        K = w1 * k1 + w2 * k2
        kb0, kb1, kb2 = Vh[6, 0], Vh[6, 1], Vh[6, 2]
        for i in range(3):
            tti = tt0 if i == 0 else (tt1 if i == 1 else tt2)
            tei = te0 if i == 0 else (te1 if i == 1 else te2)
            tfi = tf0 if i == 0 else (tf1 if i == 1 else tf2)
            Ai = A0 if i == 0 else (A1 if i == 1 else A2)
            Bi = B0 if i == 0 else (B1 if i == 1 else B2)
            kbi = kb0 if i == 0 else (kb1 if i == 1 else kb2)
            Mai = w1 * Vh[3, i] - w2 * Vh[2, i]
            Mbi = w1 * Vh[5, i] - w2 * Vh[4, i]
            for j in range(3):
                ttj = tt0 if j == 0 else (tt1 if j == 1 else tt2)
                tej = te0 if j == 0 else (te1 if j == 1 else te2)
                tfj = tf0 if j == 0 else (tf1 if j == 1 else tf2)
                Aj = A0 if j == 0 else (A1 if j == 1 else A2)
                Bj = B0 if j == 0 else (B1 if j == 1 else B2)
                kbj = kb0 if j == 0 else (kb1 if j == 1 else kb2)
                Maj = w1 * Vh[3, j] - w2 * Vh[2, j]
                Mbj = w1 * Vh[5, j] - w2 * Vh[4, j]
                dij = 1.0 if i == j else 0.0
                Kttt = 2.0 * K * tti * ttj
                See[i, j] = ine * ine * (Kttt - (Ai * ttj + tti * Aj) - K * ic * (dij - tei * tej)
                                         + 0.25 * (kbi * Maj + Mai * kbj)
                                         - 0.25 * wt * (kbi * (tej + ttj) + (tei + tti) * kbj))
                Sff[i, j] = inf * inf * (Kttt + (Bi * ttj + tti * Bj) - K * ic * (dij - tfi * tfj)
                                         + 0.25 * (kbi * Mbj + Mbi * kbj)
                                         - 0.25 * wt * (kbi * (tfj + ttj) + (tfi + tti) * kbj))
                Sef[i, j] = ine * inf * (-K * ic * (dij + tei * tfj) + Kttt - Ai * ttj + tti * Bj
                                         - _skew(Dv0, Dv1, Dv2, i, j)
                                         + wt * (ic * _skew(te0, te1, te2, i, j) - 0.5 * kbi * ttj))
        for i in range(3):
            for j in range(3):
                see, sff, sef, sfe = See[i, j], Sff[i, j], Sef[i, j], Sef[j, i]
                Hh[i, j] = see
                Hh[i, 3 + j] = -see + sef
                Hh[i, 6 + j] = -sef
                Hh[3 + i, 3 + j] = see - sef - sfe + sff
                Hh[3 + i, 6 + j] = sef - sff
                Hh[6 + i, 6 + j] = sff
                Hh[3 + j, i] = Hh[i, 3 + j]
                Hh[6 + j, i] = Hh[i, 6 + j]
                Hh[6 + j, 3 + i] = Hh[3 + i, 6 + j]
        # position-theta: theta_a turns (m1a, m2a), theta_b (m1b, m2b)
        for jj in range(2):
            r1 = 2 + 2 * jj
            kbm1 = kb0 * Vh[r1, 0] + kb1 * Vh[r1, 1] + kb2 * Vh[r1, 2]
            kbm2 = kb0 * Vh[r1 + 1, 0] + kb1 * Vh[r1 + 1, 1] + kb2 * Vh[r1 + 1, 2]
            s_ = 0.5 * (w1 * kbm1 + w2 * kbm2)
            wm0 = w1 * Vh[r1, 0] + w2 * Vh[r1 + 1, 0]
            wm1 = w1 * Vh[r1, 1] + w2 * Vh[r1 + 1, 1]
            wm2 = w1 * Vh[r1, 2] + w2 * Vh[r1 + 1, 2]
            f0, f1, f2 = cross3(tf0, tf1, tf2, wm0, wm1, wm2)
            g0, g1, g2 = cross3(te0, te1, te2, wm0, wm1, wm2)
            for i in range(3):
                tti = tt0 if i == 0 else (tt1 if i == 1 else tt2)
                fi = f0 if i == 0 else (f1 if i == 1 else f2)
                gi = g0 if i == 0 else (g1 if i == 1 else g2)
                se = ine * (s_ * tti - ic * fi)
                sf = inf * (s_ * tti + ic * gi)
                Hh[i, 9 + jj] = -se
                Hh[3 + i, 9 + jj] = se - sf
                Hh[6 + i, 9 + jj] = sf
                Hh[9 + jj, i] = -se
                Hh[9 + jj, 3 + i] = se - sf
                Hh[9 + jj, 6 + i] = sf
            # theta-theta: kappa is linear in m_a + m_b (no cross term), tau is linear in theta
            Hh[9 + jj, 9 + jj] = 0.5 * (w2 * kbm1 - w1 * kbm2)
        Hh[9, 10] = 0.0
        Hh[10, 9] = 0.0
        # plus the Gauss-Newton part; then the signs of reversed edges' twist DOFs
        kb_, kt_ = k_bend[h], k_twist[h]
        sa, sb = sign[h, 0], sign[h, 1]
        for i in range(11):
            si = sa if i == 9 else (sb if i == 10 else 1.0)
            for j in range(11):
                sj = sa if j == 9 else (sb if j == 10 else 1.0)
                Hh[i, j] = (Hh[i, j] + kb_ * (Gh[0, i] * Gh[0, j] + Gh[1, i] * Gh[1, j])
                            + kt_ * Gh[2, i] * Gh[2, j]) * si * sj


@njit(cache=True)
def _connection(t0, t1, t2, c0, c1, c2, le):
    """dOmega/de = -(t_c x t) / ((1 + t_c . t) l): the spin of the transported reference frame per change of the
    edge vector e (see _edge_holonomy). Returns (g0, g1, g2, c) with c = t_c . t."""
    c = c0 * t0 + c1 * t1 + c2 * t2
    w0, w1, w2 = cross3(c0, c1, c2, t0, t1, t2)
    f = -1.0 / ((1.0 + c) * le)
    return f * w0, f * w1, f * w2, c


@njit(cache=True)
def tangent_torque(t, tc, length, edge, tq, dtq, x_dofs, r, J, s_xx, s_xth, want_jacobian):
    """The nodal force of a torque -tq about an edge's tangent, and its Jacobian.

    When the tangent moves, the material frame spins by d(theta) + g . de (g = dOmega/de, the transport's
    connection), so the torque T = -tq does work T g . de: the residual gets +tq g on the edge's head node and
    -tq g on its tail (``x_dofs`` = [x_tail, x_head]). Jacobian: tq dg/de on the edge block [[D, -D], [-D, D]]
    (not symmetric: the torque is not conservative), and dtq/dtheta g on the twist column, with
    dg/de = [-[t_c]x / ((1 + c) l) + (t_c x t) t_c^T / ((1 + c)^2 l)] P / l - g t^T / l, P = I - t t^T."""
    t0, t1, t2 = t[edge, 0], t[edge, 1], t[edge, 2]
    c0, c1, c2 = tc[edge, 0], tc[edge, 1], tc[edge, 2]
    le = length[edge]
    g0, g1, g2, c = _connection(t0, t1, t2, c0, c1, c2, le)
    g = (g0, g1, g2)
    for i in range(3):
        r[x_dofs[i]] -= tq * g[i]
        r[x_dofs[3 + i]] += tq * g[i]
    if not want_jacobian:
        return
    tv = (t0, t1, t2)
    cv = (c0, c1, c2)
    w = cross3(c0, c1, c2, t0, t1, t2)
    a = 1.0 / ((1.0 + c) * le)
    b = 1.0 / ((1.0 + c) ** 2 * le)
    # df/dt = -a [t_c]x + b w t_c^T
    F = np.empty((3, 3))
    F[0, 0], F[0, 1], F[0, 2] = 0.0, a * c2, -a * c1
    F[1, 0], F[1, 1], F[1, 2] = -a * c2, 0.0, a * c0
    F[2, 0], F[2, 1], F[2, 2] = a * c1, -a * c0, 0.0
    for i in range(3):
        for j in range(3):
            F[i, j] += b * w[i] * cv[j]
    D = np.empty((3, 3))
    for i in range(3):
        Ft = F[i, 0] * t0 + F[i, 1] * t1 + F[i, 2] * t2
        for j in range(3):
            D[i, j] = ((F[i, j] - Ft * tv[j]) - g[i] * tv[j]) / le
    for i in range(3):
        for j in range(3):
            v = tq * D[i, j]
            J[s_xx[6 * i + j]] += v              # (tail, tail)
            J[s_xx[6 * i + 3 + j]] -= v          # (tail, head)
            J[s_xx[6 * (3 + i) + j]] -= v        # (head, tail)
            J[s_xx[6 * (3 + i) + 3 + j]] += v    # (head, head)
        J[s_xth[i]] -= dtq * g[i]
        J[s_xth[3 + i]] += dtq * g[i]


@njit(cache=True)
def _edge_holonomy(t, tc, length, g, Hh, want_hessian):
    """Per edge: dOmega/de (3) and d2Omega/de2 (3x3) of the holonomy spin Omega.

    The reference frame at a trial configuration is d = P(t_c -> t) d_c (one transport from the committed
    tangent t_c). The DER derivative formulas differentiate as if the frame moved by the *minimal* transport from
    the current tangent t. The two differ by a spin about t equal to the solid angle of the geodesic triangle
    (t_c, t, t'), which acts exactly like an extra twist angle: E(x, theta) = E_min(x, theta + Omega(x)), with
    Omega(t) = 0, dOmega/dt' = -w / (1 + c), d2Omega/dt'2 = (w u^T + u w^T) / (2 (1 + c)^2) at t' = t, where
    w = t_c x t, u = t_c + t, c = t_c . t. Projected on the edge (P w = w, P u = t_c - c t): no matrix products.
    Adding these terms makes the elastic force the exact gradient of the energy at every Newton iterate (not
    only at the committed state) and the Hessian its exact Jacobian, which keeps Newton quadratic when parts of
    the robot turn quickly.
    """
    for k in range(t.shape[0]):
        t0, t1, t2 = t[k, 0], t[k, 1], t[k, 2]
        c0, c1, c2 = tc[k, 0], tc[k, 1], tc[k, 2]
        le = length[k]
        g0, g1, g2, c = _connection(t0, t1, t2, c0, c1, c2, le)
        g[k, 0], g[k, 1], g[k, 2] = g0, g1, g2
        if not want_hessian:
            continue
        w0, w1, w2 = cross3(c0, c1, c2, t0, t1, t2)
        gt0, gt1, gt2 = g0 * le, g1 * le, g2 * le
        s = 1.0 / (2.0 * (1.0 + c) ** 2)
        il2 = 1.0 / (le * le)
        for i in range(3):
            wi = w0 if i == 0 else (w1 if i == 1 else w2)
            ui = (c0 if i == 0 else (c1 if i == 1 else c2)) - c * (t0 if i == 0 else (t1 if i == 1 else t2))
            ti = t0 if i == 0 else (t1 if i == 1 else t2)
            gi = gt0 if i == 0 else (gt1 if i == 1 else gt2)
            for j in range(3):
                wj = w0 if j == 0 else (w1 if j == 1 else w2)
                uj = (c0 if j == 0 else (c1 if j == 1 else c2)) - c * (t0 if j == 0 else (t1 if j == 1 else t2))
                tj = t0 if j == 0 else (t1 if j == 1 else t2)
                gj = gt0 if j == 0 else (gt1 if j == 1 else gt2)
                Hh[k, i, j] = (s * (wi * uj + ui * wj) - (ti * gj + gi * tj)) * il2


@njit(cache=True)
def _change_variables(grad, Hs, edges, sign, hg, hh, want_hessian):
    """Apply y_theta = theta + Omega(x) to every hinge: g <- g + g_theta dOmega/dx and
    H <- T^T H T + sum_k g_theta_k d2Omega_k, with dOmega of the hinge's two edges in its local DOFs (edge a
    joins local nodes 0-1, edge b nodes 1-2; a reversed edge flips the sign)."""
    Vh = np.zeros((2, 11))
    Ht = np.empty((2, 11))
    for h in range(grad.shape[0]):
        ea, eb = edges[h, 0], edges[h, 1]
        sa, sb = sign[h, 0], sign[h, 1]
        for i in range(3):
            Vh[0, i], Vh[0, 3 + i] = -sa * hg[ea, i], sa * hg[ea, i]
            Vh[1, 3 + i], Vh[1, 6 + i] = -sb * hg[eb, i], sb * hg[eb, i]
        gA, gB = grad[h, 9], grad[h, 10]
        if want_hessian:
            H = Hs[h]
            h99, h9a, ha9, haa = H[9, 9], H[9, 10], H[10, 9], H[10, 10]
            for j in range(11):
                Ht[0, j] = H[9, j]
                Ht[1, j] = H[10, j]
            for i in range(11):
                for j in range(11):
                    H[i, j] += (Vh[0, i] * Ht[0, j] + Vh[1, i] * Ht[1, j] + Ht[0, i] * Vh[0, j]
                                + Ht[1, i] * Vh[1, j] + Vh[0, i] * (h99 * Vh[0, j] + h9a * Vh[1, j])
                                + Vh[1, i] * (ha9 * Vh[0, j] + haa * Vh[1, j]))
            # an edge's block [[B, -B], [-B, B]] is unchanged by swapping its ends: the sign does not enter
            for i in range(3):
                for j in range(3):
                    hA = gA * hh[ea, i, j]
                    hB = gB * hh[eb, i, j]
                    H[i, j] += hA
                    H[3 + i, 3 + j] += hA + hB
                    H[i, 3 + j] -= hA
                    H[3 + i, j] -= hA
                    H[6 + i, 6 + j] += hB
                    H[3 + i, 6 + j] -= hB
                    H[6 + i, 3 + j] -= hB
        for j in range(9):
            grad[h, j] += gA * Vh[0, j] + gB * Vh[1, j]


@njit(cache=True)
def _scatter(dofs, slots, grad, Hs, r, J, want_hessian):
    """Every hinge's gradient into the residual r and its Hessian into the CSC data array J."""
    for h in range(grad.shape[0]):
        for j in range(11):
            r[dofs[h, j]] += grad[h, j]
        if want_hessian:
            for i in range(11):
                for j in range(11):
                    J[slots[h, i, j]] += Hs[h, i, j]


@njit(cache=True)
def _bend_twist(x, theta, t, tc, length, d1, d2, rt, nodes, edges, sign, beta, kappa_bar, tau_bar, k_bend,
                k_twist, dofs, slots, twist_hinge, twist_offset, r, J, want_hessian):
    """Bend + twist forces of every hinge into r (and their Hessian into J): the stages in order.

    Arguments: positions and twist angles; the trial frames (t, t_committed, length, d1, d2, reference twist);
    the springs (nodes, edges, sign, beta, rest curvature and twist, stiffnesses, local DOFs and CSC slots); the
    motor's natural-twist offset; the outputs."""
    H, Ne = nodes.shape[0], t.shape[0]
    V = np.empty((H, 7, 3))
    S = np.empty((H, 6))
    W = np.empty((H, 3))
    G = np.empty((H, 3, 11))
    grad = np.empty((H, 11))
    Hs = np.empty((H, 11, 11)) if want_hessian else np.empty((0, 11, 11))
    hg = np.empty((Ne, 3))
    hh = np.empty((Ne, 3, 3)) if want_hessian else np.empty((0, 3, 3))
    _hinge_geometry(x, theta, d1, d2, rt, nodes, edges, sign, beta, V, S)
    _hinge_weights(S, kappa_bar, tau_bar, twist_hinge, twist_offset, k_bend, k_twist, W)
    _strain_gradients(V, S, G)
    _gradients(G, W, sign, grad)
    if want_hessian:
        _hessians(V, S, W, G, sign, k_bend, k_twist, Hs)
    _edge_holonomy(t, tc, length, hg, hh, want_hessian)
    _change_variables(grad, Hs, edges, sign, hg, hh, want_hessian)
    _scatter(dofs, slots, grad, Hs, r, J, want_hessian)


@njit(cache=True)
def _hinge_strains(x, theta, d1, d2, rt, nodes, edges, sign, beta, k1s, k2s, taus):
    H = nodes.shape[0]
    V = np.empty((H, 7, 3))
    S = np.empty((H, 6))
    _hinge_geometry(x, theta, d1, d2, rt, nodes, edges, sign, beta, V, S)
    for h in range(H):
        k1s[h], k2s[h], taus[h] = S[h, 3], S[h, 4], S[h, 5]


@njit(cache=True)
def _bend_twist_energy(x, theta, d1, d2, rt, nodes, edges, sign, beta, kappa_bar, tau_bar, k_bend, k_twist,
                       twist_hinge, twist_offset):
    H = nodes.shape[0]
    V = np.empty((H, 7, 3))
    S = np.empty((H, 6))
    _hinge_geometry(x, theta, d1, d2, rt, nodes, edges, sign, beta, V, S)
    return _hinge_energy(S, kappa_bar, tau_bar, twist_hinge, twist_offset, k_bend, k_twist)


# ----------------------------------------------------------------------------------------------- the model
def spring_dofs(net: RodNetwork) -> tuple[np.ndarray, np.ndarray]:
    """DOFs of every stretching spring (Ne, 6: both end nodes) and bend-twist hinge (H, 11: [x_a, x_b, x_c,
    theta_ea, theta_eb]): the elastic blocks of the Jacobian pattern."""
    E = net.edges
    hn, he = net.hinge_nodes, net.hinge_edges
    stretch = np.concatenate([net.node_dofs(E[:, 0]), net.node_dofs(E[:, 1])], axis=1)
    hinge = np.concatenate([net.node_dofs(hn[:, 0]), net.node_dofs(hn[:, 1]), net.node_dofs(hn[:, 2]),
                            net.edge_dof(he)], axis=1)
    return stretch, hinge


class ElasticModel:
    """Stretching + bend-twist springs of a :class:`RodNetwork`.

    ``tau_bar`` is the natural twist of every hinge at rest; the motor's advance is not stored here but passed
    with each evaluation (``twist_hinge``, ``twist_offset``), so evaluating a trial step changes nothing.
    """

    def __init__(self, net: RodNetwork):
        self.net = net
        N = net.n_nodes
        self.n_nodes = N
        self.ndof = net.ndof
        E = net.edges
        self.stretch_dofs, self.hinge_dofs = spring_dofs(net)
        self.sign = net.hinge_sign
        self.k_bend = net.EI / net.voronoi
        self.k_twist = net.GJ / net.voronoi
        self.stretch_slots = np.zeros((net.n_edges, 6, 6), np.int64)
        self.hinge_slots = np.zeros((net.n_hinges, 11, 11), np.int64)
        # rest strains from the undeformed configuration with theta = 0
        q0 = net.initial_q()
        x0 = self.positions(q0)
        t0 = x0[E[:, 1]] - x0[E[:, 0]]
        t0 /= np.linalg.norm(t0, axis=1)[:, None]
        self.frames0 = EdgeFrames.initial(t0, net.n_hinges)
        self.beta = np.zeros(net.n_hinges)
        self.kappa_bar = np.zeros((net.n_hinges, 2))
        self.tau_bar = np.zeros(net.n_hinges)
        tf = self.trial_frames(q0, self.frames0)
        self.frames0.ref_twist = tf.ref_twist.copy()
        # Frame offset per hinge: turn edge a's frame by its rest reference twist so that the two material frames
        # a hinge averages are aligned at rest. Without it, a 90-degree hinge whose frames start a half turn
        # apart has m_a + m_b = 0: its curvature loses a direction and the "rigid" plate flops about the joint.
        self.beta = tf.ref_twist.copy()
        k1, k2, tau = self.hinge_strains(q0, tf)
        self.kappa_bar = np.stack([k1, k2], axis=1)
        self.tau_bar = tau.copy()

    def positions(self, q: np.ndarray) -> np.ndarray:
        return q[: 3 * self.n_nodes].reshape(self.n_nodes, 3)

    def trial_frames(self, q: np.ndarray, committed: EdgeFrames) -> TrialFrames:
        return trial_frames(self.positions(q), self.net.edges, self.net.hinge_edges, self.sign, committed)

    def set_slots(self, stretch_slots: np.ndarray, hinge_slots: np.ndarray) -> None:
        """Positions in the CSC data array of every stretch (6x6) and hinge (11x11) Jacobian entry."""
        self.stretch_slots = np.ascontiguousarray(stretch_slots.reshape(-1, 6, 6))
        self.hinge_slots = np.ascontiguousarray(hinge_slots.reshape(-1, 11, 11))

    # ------------------------------------------------------------------ strains and energy
    def hinge_strains(self, q: np.ndarray, fr: TrialFrames):
        """(kappa1, kappa2, tau) of every hinge; tau without the natural twist."""
        H = self.net.n_hinges
        k1, k2, tau = np.empty(H), np.empty(H), np.empty(H)
        net = self.net
        _hinge_strains(self.positions(q), q[3 * self.n_nodes:], fr.d1, fr.d2, fr.ref_twist, net.hinge_nodes,
                       net.hinge_edges, self.sign, self.beta, k1, k2, tau)
        return k1, k2, tau

    def stretch_strain(self, fr: TrialFrames) -> np.ndarray:
        return fr.length / self.net.edge_rest_length - 1.0

    def energy(self, q: np.ndarray, fr: TrialFrames, twist_hinge: int = -1, twist_offset: float = 0.0) -> float:
        net = self.net
        return float(_stretch_energy(fr.length, net.edge_rest_length, net.EA)
                     + _bend_twist_energy(self.positions(q), q[3 * self.n_nodes:], fr.d1, fr.d2, fr.ref_twist,
                                          net.hinge_nodes, net.hinge_edges, self.sign, self.beta, self.kappa_bar,
                                          self.tau_bar, self.k_bend, self.k_twist, twist_hinge, twist_offset))

    # ------------------------------------------------------------------ into the global system
    def accumulate(self, q: np.ndarray, fr: TrialFrames, r: np.ndarray, J: np.ndarray | None,
                   twist_hinge: int = -1, twist_offset: float = 0.0) -> None:
        """Add the elastic gradient to r and, if J (CSC data array) is given, the Hessian to J."""
        want = J is not None
        d = J if want else np.empty(0)
        net = self.net
        _stretch(fr.t, fr.length, net.edge_rest_length, net.EA, self.stretch_dofs, self.stretch_slots, r, d, want)
        _bend_twist(self.positions(q), q[3 * self.n_nodes:], fr.t, fr.t_committed, fr.length, fr.d1, fr.d2,
                    fr.ref_twist, net.hinge_nodes, net.hinge_edges, self.sign, self.beta, self.kappa_bar,
                    self.tau_bar, self.k_bend, self.k_twist, self.hinge_dofs, self.hinge_slots, twist_hinge,
                    twist_offset, r, d, want)
