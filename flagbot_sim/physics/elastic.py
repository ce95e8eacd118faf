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

and ``_bend_twist_local`` (the first five) and ``_bend_twist_global`` (the last three) run them. Energy, gradient
and Hessian come from the same stages, so the finite-difference tests check the code that runs.
"""
from __future__ import annotations

import math
import numpy as np

from .frames import EdgeFrames, TrialFrames, cross3, trial_frames
from .jit import kernel, stage
from .network import RodNetwork

# ----------------------------------------------------------------------------------------------- stretching
@kernel
def _stretch(t, length, rest, EA, dofs, slots, r, J, want_hessian):
    """E = 1/2 EA (l/l0 - 1)^2 l0 per edge: gradient into r, Hessian into J (``slots`` (Ne, 36): the edge's
    6x6 block, row-major)."""
    for k in range(t.shape[0]):
        L0 = rest[k]
        f = EA[k] * (length[k] / L0 - 1.0)
        dk = dofs[k]
        for i in range(3):
            ti = t[k, i]
            r[dk[i]] -= f * ti
            r[dk[3 + i]] += f * ti
        if want_hessian:
            a = EA[k] / L0
            b = EA[k] * (1.0 / L0 - 1.0 / length[k])
            sk = slots[k]
            for i in range(3):
                for j in range(3):
                    tt = t[k, i] * t[k, j]
                    K = a * tt + b * ((1.0 if i == j else 0.0) - tt)
                    J[sk[6 * i + j]] += K
                    J[sk[6 * (3 + i) + 3 + j]] += K
                    J[sk[6 * i + 3 + j]] -= K
                    J[sk[6 * (3 + i) + j]] -= K


@kernel
def _stretch_energy(length, rest, EA):
    E = 0.0
    for k in range(length.shape[0]):
        eps = length[k] / rest[k] - 1.0
        E += 0.5 * EA[k] * eps * eps * rest[k]
    return E


# ----------------------------------------------------------------------------------------------- hinge stages
# Each stage is one loop over all hinges with its formula written on local scalars; the stages hand arrays over
# all hinges to each other, one flat row per hinge: V (21) the hinge's 3-vectors, S (6) its scalars, G (33) the
# strain gradients, Hs (121) its Hessian, row-major. (A per-hinge function taking the spring arrays was 6x
# slower: numba passes every array struct by value at every call. Flat rows compile to half the code of 2-D
# ones: every index of an array access costs its own bounds arithmetic.)

#: offsets of the 3-vectors in a row of V: unit edge tangents, material directors, curvature binormal
TE, TF, M1A, M2A, M1B, M2B, KB = 0, 3, 6, 9, 12, 15, 18


@stage
def _hinge_geometry(x, theta, d1, d2, rt, nodes, edges, sign, beta, V, S):
    """Kinematics and strains of every hinge (paper Eqs. curvature, BendingCurvature1/2, twistingEnergy).

    V[h] (21): unit edge tangents te, tf, material directors m1a, m2a, m1b, m2b, curvature binormal kb (offsets
    TE ... KB). S[h] (6): edge lengths ne, nf, chi = 1 + te.tf, kappa1, kappa2, and the twist tau without
    natural twist."""
    for h in range(nodes.shape[0]):
        a, b, c = nodes[h, 0], nodes[h, 1], nodes[h, 2]
        ea, eb = edges[h, 0], edges[h, 1]
        sa, sb = sign[h, 0], sign[h, 1]
        xa0, xa1, xa2 = x[a, 0], x[a, 1], x[a, 2]
        xb0, xb1, xb2 = x[b, 0], x[b, 1], x[b, 2]
        xc0, xc1, xc2 = x[c, 0], x[c, 1], x[c, 2]
        e0, e1, e2 = xb0 - xa0, xb1 - xa1, xb2 - xa2
        f0, f1, f2 = xc0 - xb0, xc1 - xb1, xc2 - xb2
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
        Vh[TE], Vh[TE + 1], Vh[TE + 2] = e0, e1, e2
        Vh[TF], Vh[TF + 1], Vh[TF + 2] = f0, f1, f2
        Vh[KB], Vh[KB + 1], Vh[KB + 2] = kb0, kb1, kb2
        k1 = 0.0
        k2 = 0.0
        for i in range(3):
            # an edge traversed against its direction enters with the reference frame (d1, -d2)
            d1a, d2a, d1b, d2b = d1[ea, i], d2[ea, i], d1[eb, i], d2[eb, i]
            m1a = ca * d1a + sna * sa * d2a
            m2a = -sna * d1a + ca * sa * d2a
            m1b = cb * d1b + snb * sb * d2b
            m2b = -snb * d1b + cb * sb * d2b
            Vh[M1A + i], Vh[M2A + i], Vh[M1B + i], Vh[M2B + i] = m1a, m2a, m1b, m2b
            kbi = Vh[KB + i]
            k1 += 0.5 * kbi * (m2a + m2b)
            k2 -= 0.5 * kbi * (m1a + m1b)
        Sh = S[h]
        Sh[0], Sh[1], Sh[2], Sh[3], Sh[4], Sh[5] = ne, nf, chi, k1, k2, thb - tha + rt[h]


@stage
def _hinge_weights(S, kappa_bar, tau_bar, twist_hinge, twist_offset, k_bend, k_twist, W):
    """W[h] = (w1, w2, wt) = k_i (s_i - s_i_bar): the energy's derivative w.r.t. each strain. The natural twist
    of hinge ``twist_hinge`` is shifted by ``twist_offset`` (the motor, paper Eq. SpecifyTheta)."""
    for h in range(S.shape[0]):
        tb = tau_bar[h] + (twist_offset if h == twist_hinge else 0.0)
        Sh, Wh = S[h], W[h]
        Wh[0] = k_bend[h] * (Sh[3] - kappa_bar[h, 0])
        Wh[1] = k_bend[h] * (Sh[4] - kappa_bar[h, 1])
        Wh[2] = k_twist[h] * (Sh[5] - tb)


@stage
def _hinge_energy(S, kappa_bar, tau_bar, twist_hinge, twist_offset, k_bend, k_twist):
    E = 0.0
    for h in range(S.shape[0]):
        tb = tau_bar[h] + (twist_offset if h == twist_hinge else 0.0)
        dk1, dk2, dt = S[h, 3] - kappa_bar[h, 0], S[h, 4] - kappa_bar[h, 1], S[h, 5] - tb
        E += 0.5 * k_bend[h] * (dk1 * dk1 + dk2 * dk2) + 0.5 * k_twist[h] * dt * dt
    return E


@stage
def _strain_gradients(V, S, G):
    """G[h] (33: three rows of 11): gradients of kappa1, kappa2, tau w.r.t. [x_a, x_b, x_c, theta_a, theta_b]
    (edges unsigned).

    In edge space (e = x_b - x_a, f = x_c - x_b), with tt = (te + tf)/chi, d1~ = (m1a + m1b)/chi,
    d2~ = (m2a + m2b)/chi: dk1/de = (-k1 tt + tf x d2~)/|e|, dk1/df = (-k1 tt - te x d2~)/|f|,
    dk2/de = (-k2 tt - tf x d1~)/|e|, dk2/df = (-k2 tt + te x d1~)/|f|, dtau/de = kb/(2|e|), dtau/df = kb/(2|f|)
    (the last through the reference twist), mapped to nodes by x_a = -e, x_b = e - f, x_c = f."""
    X = np.empty(12)              # tf x d2~, te x d2~, tf x d1~, te x d1~
    for h in range(V.shape[0]):
        Vh, Gh, Sh = V[h], G[h], S[h]
        ne, nf, chi, k1, k2 = Sh[0], Sh[1], Sh[2], Sh[3], Sh[4]
        ic, ine, inf = 1.0 / chi, 1.0 / ne, 1.0 / nf
        te0, te1, te2 = Vh[TE], Vh[TE + 1], Vh[TE + 2]
        tf0, tf1, tf2 = Vh[TF], Vh[TF + 1], Vh[TF + 2]
        m1a0, m1a1, m1a2 = Vh[M1A], Vh[M1A + 1], Vh[M1A + 2]
        m2a0, m2a1, m2a2 = Vh[M2A], Vh[M2A + 1], Vh[M2A + 2]
        m1b0, m1b1, m1b2 = Vh[M1B], Vh[M1B + 1], Vh[M1B + 2]
        m2b0, m2b1, m2b2 = Vh[M2B], Vh[M2B + 1], Vh[M2B + 2]
        kb0, kb1, kb2 = Vh[KB], Vh[KB + 1], Vh[KB + 2]
        d10, d11, d12 = (m1a0 + m1b0) * ic, (m1a1 + m1b1) * ic, (m1a2 + m1b2) * ic
        d20, d21, d22 = (m2a0 + m2b0) * ic, (m2a1 + m2b1) * ic, (m2a2 + m2b2) * ic
        X[0], X[1], X[2] = cross3(tf0, tf1, tf2, d20, d21, d22)
        X[3], X[4], X[5] = cross3(te0, te1, te2, d20, d21, d22)
        X[6], X[7], X[8] = cross3(tf0, tf1, tf2, d10, d11, d12)
        X[9], X[10], X[11] = cross3(te0, te1, te2, d10, d11, d12)
        for i in range(3):
            tti = (Vh[TE + i] + Vh[TF + i]) * ic
            kbi = Vh[KB + i]
            de0 = (-k1 * tti + X[i]) * ine
            df0 = (-k1 * tti - X[3 + i]) * inf
            de1 = (-k2 * tti - X[6 + i]) * ine
            df1 = (-k2 * tti + X[9 + i]) * inf
            de2 = 0.5 * kbi * ine
            df2 = 0.5 * kbi * inf
            Gh[i], Gh[3 + i], Gh[6 + i] = -de0, de0 - df0, df0
            Gh[11 + i], Gh[14 + i], Gh[17 + i] = -de1, de1 - df1, df1
            Gh[22 + i], Gh[25 + i], Gh[28 + i] = -de2, de2 - df2, df2
        kbm1a = kb0 * m1a0 + kb1 * m1a1 + kb2 * m1a2
        kbm2a = kb0 * m2a0 + kb1 * m2a1 + kb2 * m2a2
        kbm1b = kb0 * m1b0 + kb1 * m1b1 + kb2 * m1b2
        kbm2b = kb0 * m2b0 + kb1 * m2b1 + kb2 * m2b2
        Gh[9], Gh[10] = -0.5 * kbm1a, -0.5 * kbm1b
        Gh[20], Gh[21] = -0.5 * kbm2a, -0.5 * kbm2b
        Gh[31], Gh[32] = -1.0, 1.0


@stage
def _gradients(G, W, sign, grad):
    """grad[h] (11) = sum_i w_i grad(s_i), with the twist DOFs of reversed edges signed."""
    for h in range(G.shape[0]):
        Gh, gh = G[h], grad[h]
        w1, w2, wt = W[h, 0], W[h, 1], W[h, 2]
        for j in range(9):
            gh[j] = w1 * Gh[j] + w2 * Gh[11 + j] + wt * Gh[22 + j]
        gh[9] = (w1 * Gh[9] + w2 * Gh[20] + wt * Gh[31]) * sign[h, 0]
        gh[10] = (w1 * Gh[10] + w2 * Gh[21] + wt * Gh[32]) * sign[h, 1]


@stage
def _skew(v0, v1, v2, i, j):
    """Entry (i, j) of [v]x (the matrix with [v]x u = v x u): -eps_ijk v_k."""
    if i == j:
        return 0.0
    k = 3 - i - j
    vk = v0 if k == 0 else (v1 if k == 1 else v2)
    return -vk if (j - i) % 3 == 1 else vk


@stage
def _hessians(V, S, W, G, sign, k_bend, k_twist, Hs):
    """Hs[h] (121: 11 x 11, row-major): the energy's Hessian w.r.t. the hinge's local DOFs,
    sum_i k_i grad(s_i) grad(s_i)^T + sum_i w_i d2(s_i), twist DOFs of reversed edges signed.

    The weighted curvature Hessians are linear in the frame vectors, so they are formed directly from
    K = w1 k1 + w2 k2 and Dv = w1 d2~ - w2 d1~ instead of one Hessian per strain (Bergou et al. 2010; Jawed et
    al. 2018), in edge space (blocks S_ee, S_ff, S_ef) and then mapped to nodes by x_a = -e, x_b = e - f, x_c = f."""
    See = np.empty(9)
    Sff = np.empty(9)
    Sef = np.empty(9)
    # the hinge's 3-vectors by row (the loops below index them: a chain of conditional expressions picking one
    # of three scalars compiles to far more code for the same arithmetic)
    P = np.empty(24)
    TT, A, B, MA, MB, SG = 0, 3, 6, 9, 12, 15
    for h in range(V.shape[0]):
        Vh, Hh, Gh, Sh = V[h], Hs[h], G[h], S[h]
        ne, nf, chi, k1, k2 = Sh[0], Sh[1], Sh[2], Sh[3], Sh[4]
        w1, w2, wt = W[h, 0], W[h, 1], W[h, 2]
        ic, ine, inf = 1.0 / chi, 1.0 / ne, 1.0 / nf
        te0, te1, te2 = Vh[TE], Vh[TE + 1], Vh[TE + 2]
        tf0, tf1, tf2 = Vh[TF], Vh[TF + 1], Vh[TF + 2]
        for i in range(3):
            m1ai, m2ai, m1bi, m2bi = Vh[M1A + i], Vh[M2A + i], Vh[M1B + i], Vh[M2B + i]
            P[TT + i] = (Vh[TE + i] + Vh[TF + i]) * ic
            P[MA + i] = w1 * m2ai - w2 * m1ai
            P[MB + i] = w1 * m2bi - w2 * m1bi
            P[SG + i] = (w1 * (m2ai + m2bi) - w2 * (m1ai + m1bi)) * ic       # Dv
        Dv0, Dv1, Dv2 = P[SG], P[SG + 1], P[SG + 2]
        P[A], P[A + 1], P[A + 2] = cross3(tf0, tf1, tf2, Dv0, Dv1, Dv2)
        P[B], P[B + 1], P[B + 2] = cross3(te0, te1, te2, Dv0, Dv1, Dv2)
        K = w1 * k1 + w2 * k2
        for i in range(3):
            tti, tei, tfi, Ai, Bi = P[TT + i], Vh[TE + i], Vh[TF + i], P[A + i], P[B + i]
            kbi, Mai, Mbi = Vh[KB + i], P[MA + i], P[MB + i]
            for j in range(3):
                ttj, tej, tfj, Aj, Bj = P[TT + j], Vh[TE + j], Vh[TF + j], P[A + j], P[B + j]
                kbj, Maj, Mbj = Vh[KB + j], P[MA + j], P[MB + j]
                dij = 1.0 if i == j else 0.0
                Kttt = 2.0 * K * tti * ttj
                See[3 * i + j] = ine * ine * (Kttt - (Ai * ttj + tti * Aj) - K * ic * (dij - tei * tej)
                                              + 0.25 * (kbi * Maj + Mai * kbj)
                                              - 0.25 * wt * (kbi * (tej + ttj) + (tei + tti) * kbj))
                Sff[3 * i + j] = inf * inf * (Kttt + (Bi * ttj + tti * Bj) - K * ic * (dij - tfi * tfj)
                                              + 0.25 * (kbi * Mbj + Mbi * kbj)
                                              - 0.25 * wt * (kbi * (tfj + ttj) + (tfi + tti) * kbj))
                Sef[3 * i + j] = ine * inf * (-K * ic * (dij + tei * tfj) + Kttt - Ai * ttj + tti * Bj
                                              - _skew(Dv0, Dv1, Dv2, i, j)
                                              + wt * (ic * _skew(te0, te1, te2, i, j) - 0.5 * kbi * ttj))
        for i in range(3):
            for j in range(3):
                see, sff, sef, sfe = See[3 * i + j], Sff[3 * i + j], Sef[3 * i + j], Sef[3 * j + i]
                a_b = -see + sef
                a_c = -sef
                b_c = sef - sff
                Hh[11 * i + j] = see
                Hh[11 * i + 3 + j] = a_b
                Hh[11 * i + 6 + j] = a_c
                Hh[11 * (3 + i) + 3 + j] = see - sef - sfe + sff
                Hh[11 * (3 + i) + 6 + j] = b_c
                Hh[11 * (6 + i) + 6 + j] = sff
                Hh[11 * (3 + j) + i] = a_b
                Hh[11 * (6 + j) + i] = a_c
                Hh[11 * (6 + j) + 3 + i] = b_c
        # position-theta: theta_a turns (m1a, m2a), theta_b (m1b, m2b)
        kb0, kb1, kb2 = Vh[KB], Vh[KB + 1], Vh[KB + 2]
        for jj in range(2):
            r1 = M1A + 6 * jj
            r2 = r1 + 3
            kbm1 = kb0 * Vh[r1] + kb1 * Vh[r1 + 1] + kb2 * Vh[r1 + 2]
            kbm2 = kb0 * Vh[r2] + kb1 * Vh[r2 + 1] + kb2 * Vh[r2 + 2]
            s_ = 0.5 * (w1 * kbm1 + w2 * kbm2)
            wm0 = w1 * Vh[r1] + w2 * Vh[r2]
            wm1 = w1 * Vh[r1 + 1] + w2 * Vh[r2 + 1]
            wm2 = w1 * Vh[r1 + 2] + w2 * Vh[r2 + 2]
            P[A], P[A + 1], P[A + 2] = cross3(tf0, tf1, tf2, wm0, wm1, wm2)
            P[B], P[B + 1], P[B + 2] = cross3(te0, te1, te2, wm0, wm1, wm2)
            for i in range(3):
                se = ine * (s_ * P[TT + i] - ic * P[A + i])
                sf = inf * (s_ * P[TT + i] + ic * P[B + i])
                Hh[11 * i + 9 + jj] = -se
                Hh[11 * (3 + i) + 9 + jj] = se - sf
                Hh[11 * (6 + i) + 9 + jj] = sf
                Hh[11 * (9 + jj) + i] = -se
                Hh[11 * (9 + jj) + 3 + i] = se - sf
                Hh[11 * (9 + jj) + 6 + i] = sf
            # theta-theta: kappa is linear in m_a + m_b (no cross term), tau is linear in theta
            Hh[12 * (9 + jj)] = 0.5 * (w2 * kbm1 - w1 * kbm2)
        Hh[11 * 9 + 10] = 0.0
        Hh[11 * 10 + 9] = 0.0
        # plus the Gauss-Newton part; then the signs of reversed edges' twist DOFs
        kb_, kt_ = k_bend[h], k_twist[h]
        sa, sb = sign[h, 0], sign[h, 1]
        for i in range(11):
            si = sa if i == 9 else (sb if i == 10 else 1.0)
            g0i, g1i, g2i = Gh[i], Gh[11 + i], Gh[22 + i]
            for j in range(11):
                sj = sa if j == 9 else (sb if j == 10 else 1.0)
                Hh[11 * i + j] = (Hh[11 * i + j] + kb_ * (g0i * Gh[j] + g1i * Gh[11 + j])
                                  + kt_ * g2i * Gh[22 + j]) * si * sj


@stage
def _connection(t0, t1, t2, c0, c1, c2, le):
    """dOmega/de = -(t_c x t) / ((1 + t_c . t) l): the spin of the transported reference frame per change of the
    edge vector e (see _edge_holonomy). Returns (g0, g1, g2, c) with c = t_c . t."""
    c = c0 * t0 + c1 * t1 + c2 * t2
    w0, w1, w2 = cross3(c0, c1, c2, t0, t1, t2)
    f = -1.0 / ((1.0 + c) * le)
    return f * w0, f * w1, f * w2, c


@kernel
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
    a_, b_ = x_dofs[:3], x_dofs[3:]
    r[a_[0]] -= tq * g0
    r[a_[1]] -= tq * g1
    r[a_[2]] -= tq * g2
    r[b_[0]] += tq * g0
    r[b_[1]] += tq * g1
    r[b_[2]] += tq * g2
    if not want_jacobian:
        return
    # the vectors g, t, t_c, w = t_c x t by row (a tuple indexed by a loop variable compiles to a switch at
    # every use)
    V = np.empty(12)
    V[0], V[1], V[2] = g0, g1, g2
    V[3], V[4], V[5] = t0, t1, t2
    V[6], V[7], V[8] = c0, c1, c2
    V[9], V[10], V[11] = cross3(c0, c1, c2, t0, t1, t2)
    a = 1.0 / ((1.0 + c) * le)
    b = 1.0 / (((1.0 + c) * (1.0 + c)) * le)
    # df/dt = -a [t_c]x + b w t_c^T, row-major
    F = np.empty(9)
    F[0], F[1], F[2] = 0.0, a * c2, -a * c1
    F[3], F[4], F[5] = -a * c2, 0.0, a * c0
    F[6], F[7], F[8] = a * c1, -a * c0, 0.0
    for i in range(3):
        for j in range(3):
            F[3 * i + j] += b * V[9 + i] * V[6 + j]
    for i in range(3):
        Fi0, Fi1, Fi2 = F[3 * i], F[3 * i + 1], F[3 * i + 2]
        Ft = Fi0 * t0 + Fi1 * t1 + Fi2 * t2
        gi = V[i]
        for j in range(3):
            tj = V[3 + j]
            v = tq * (((F[3 * i + j] - Ft * tj) - gi * tj) / le)
            J[s_xx[6 * i + j]] += v              # (tail, tail)
            J[s_xx[6 * i + 3 + j]] -= v          # (tail, head)
            J[s_xx[6 * (3 + i) + j]] -= v        # (head, tail)
            J[s_xx[6 * (3 + i) + 3 + j]] += v    # (head, head)
        J[s_xth[i]] -= dtq * gi
        J[s_xth[3 + i]] += dtq * gi



@kernel
def tangent_torques(t, tc, length, edges, tq, dtq, x_dofs, r, J, s_xx, s_xth, want_jacobian):
    """:func:`tangent_torque` for every edge of ``edges`` (torques -tq[k] about their tangents, d tq / d theta =
    dtq[k]): ``x_dofs`` (E, 6), ``s_xx`` (E, 36), ``s_xth`` (E, 6), one row per edge (zero-length rows are not
    read without the Jacobian). A distributed torque about the tangents (the flagella's spin drag) in one call."""
    for k in range(edges.shape[0]):
        tangent_torque(t, tc, length, edges[k], tq[k], dtq[k], x_dofs[k], r, J, s_xx[k], s_xth[k],
                       want_jacobian)

@stage
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
    T = np.empty(12)             # w, u, t, l g: the vectors of the formula, by row
    for k in range(t.shape[0]):
        t0, t1, t2 = t[k, 0], t[k, 1], t[k, 2]
        c0, c1, c2 = tc[k, 0], tc[k, 1], tc[k, 2]
        le = length[k]
        g0, g1, g2, c = _connection(t0, t1, t2, c0, c1, c2, le)
        g[k, 0], g[k, 1], g[k, 2] = g0, g1, g2
        if not want_hessian:
            continue
        T[0], T[1], T[2] = cross3(c0, c1, c2, t0, t1, t2)
        T[3], T[4], T[5] = c0 - c * t0, c1 - c * t1, c2 - c * t2
        T[6], T[7], T[8] = t0, t1, t2
        T[9], T[10], T[11] = g0 * le, g1 * le, g2 * le
        s = 1.0 / (2.0 * ((1.0 + c) * (1.0 + c)))
        il2 = 1.0 / (le * le)
        hk = Hh[k]
        for i in range(3):
            wi, ui, ti, gi = T[i], T[3 + i], T[6 + i], T[9 + i]
            for j in range(3):
                hk[3 * i + j] = (s * (wi * T[3 + j] + ui * T[j]) - (ti * T[9 + j] + gi * T[6 + j])) * il2


@stage
def _change_variables(grad, Hs, edges, sign, hg, hh, want_hessian):
    """Apply y_theta = theta + Omega(x) to every hinge: g <- g + g_theta dOmega/dx and
    H <- T^T H T + sum_k g_theta_k d2Omega_k, with dOmega of the hinge's two edges in its local DOFs (edge a
    joins local nodes 0-1, edge b nodes 1-2; a reversed edge flips the sign)."""
    Vh = np.empty(22)            # dOmega of edge a (0:11) and of edge b (11:22) in the local DOFs
    for m in range(22):          # (np.zeros would compile two more functions)
        Vh[m] = 0.0
    Ht = np.empty(22)            # rows 9 and 10 of the hinge's Hessian before the change
    for h in range(grad.shape[0]):
        ea, eb = edges[h, 0], edges[h, 1]
        sa, sb = sign[h, 0], sign[h, 1]
        for i in range(3):
            ga, gb = hg[ea, i], hg[eb, i]
            Vh[i], Vh[3 + i] = -sa * ga, sa * ga
            Vh[14 + i], Vh[17 + i] = -sb * gb, sb * gb
        gh = grad[h]
        gA, gB = gh[9], gh[10]
        if want_hessian:
            H = Hs[h]
            h99, h9a, ha9, haa = H[108], H[109], H[119], H[120]
            for j in range(11):
                Ht[j] = H[99 + j]
                Ht[11 + j] = H[110 + j]
            for i in range(11):
                v0i, v1i, t0i, t1i = Vh[i], Vh[11 + i], Ht[i], Ht[11 + i]
                for j in range(11):
                    v0j, v1j = Vh[j], Vh[11 + j]
                    H[11 * i + j] += (v0i * Ht[j] + v1i * Ht[11 + j] + t0i * v0j
                                      + t1i * v1j + v0i * (h99 * v0j + h9a * v1j)
                                      + v1i * (ha9 * v0j + haa * v1j))
            # an edge's block [[B, -B], [-B, B]] is unchanged by swapping its ends: the sign does not enter
            for i in range(3):
                for j in range(3):
                    hA = gA * hh[ea, 3 * i + j]
                    hB = gB * hh[eb, 3 * i + j]
                    H[11 * i + j] += hA
                    H[11 * (3 + i) + 3 + j] += hA + hB
                    H[11 * i + 3 + j] -= hA
                    H[11 * (3 + i) + j] -= hA
                    H[11 * (6 + i) + 6 + j] += hB
                    H[11 * (3 + i) + 6 + j] -= hB
                    H[11 * (6 + i) + 3 + j] -= hB
        for j in range(9):
            gh[j] += gA * Vh[j] + gB * Vh[11 + j]


@stage
def _scatter(dofs, slots, grad, Hs, r, J, want_hessian):
    """Every hinge's gradient into the residual r and its Hessian into the CSC data array J (``slots`` (H,
    121): the hinge's 11 x 11 block, row-major)."""
    for h in range(grad.shape[0]):
        dh, gh = dofs[h], grad[h]
        for j in range(11):
            r[dh[j]] += gh[j]
        if want_hessian:
            sh, Hh = slots[h], Hs[h]
            for m in range(121):
                J[sh[m]] += Hh[m]


@kernel
def _bend_twist_local(x, theta, d1, d2, rt, nodes, edges, sign, beta, kappa_bar, tau_bar, k_bend, k_twist,
                      twist_hinge, twist_offset, S, W, grad, Hs, want_hessian):
    """The bend-twist springs in every hinge's local DOFs, the first half of the stages: S (H, 6) each hinge's
    lengths and strains (see _hinge_geometry: what ElasticModel.hinge_strains reads), W (H, 3) its moments
    (_hinge_weights: ElasticModel.hinge_moments), grad (H, 11) its gradient and, if ``want_hessian``, Hs (H,
    121) its Hessian. Arguments: positions and twist angles; the trial frames (d1, d2, reference twist); the
    springs (nodes, edges, sign, beta, rest curvature and twist, stiffnesses); the motor's natural-twist offset.

    Two kernels (this one and :func:`_bend_twist_global`), not one, so that a first run's compile of the springs
    splits between two processes (warmup.py); both always run together, in this order."""
    H = nodes.shape[0]
    V = np.empty((H, 21))
    G = np.empty((H, 33))
    _hinge_geometry(x, theta, d1, d2, rt, nodes, edges, sign, beta, V, S)
    _hinge_weights(S, kappa_bar, tau_bar, twist_hinge, twist_offset, k_bend, k_twist, W)
    _strain_gradients(V, S, G)
    _gradients(G, W, sign, grad)
    if want_hessian:
        _hessians(V, S, W, G, sign, k_bend, k_twist, Hs)


@kernel
def _bend_twist_global(t, tc, length, edges, sign, dofs, slots, grad, Hs, r, J, want_hessian):
    """The second half: every hinge's gradient (and Hessian) from :func:`_bend_twist_local` through the change of
    variables of the reference frames' transport (t, t_committed, length) into the residual r (and the CSC data
    array J) at the springs' DOFs and slots."""
    Ne = t.shape[0]
    hg = np.empty((Ne, 3))
    hh = np.empty((Ne, 9)) if want_hessian else np.empty((0, 9))
    _edge_holonomy(t, tc, length, hg, hh, want_hessian)
    _change_variables(grad, Hs, edges, sign, hg, hh, want_hessian)
    _scatter(dofs, slots, grad, Hs, r, J, want_hessian)


@kernel
def _bend_twist_energy(x, theta, d1, d2, rt, nodes, edges, sign, beta, kappa_bar, tau_bar, k_bend, k_twist,
                       twist_hinge, twist_offset):
    H = nodes.shape[0]
    V = np.empty((H, 21))
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
        self.stretch_slots = np.zeros((net.n_edges, 36), np.int64)
        self.hinge_slots = np.zeros((net.n_hinges, 121), np.int64)
        self._strains = np.empty((net.n_hinges, 6))           # _bend_twist's per-hinge strains, a work array
        self._moments = np.empty((net.n_hinges, 3))           # and moments
        self._grad = np.empty((net.n_hinges, 11))             # every hinge's local gradient and Hessian
        self._Hs = np.empty((net.n_hinges, 121))
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
        self.stretch_slots = np.ascontiguousarray(stretch_slots.reshape(-1, 36))
        self.hinge_slots = np.ascontiguousarray(hinge_slots.reshape(-1, 121))

    # ------------------------------------------------------------------ strains and energy
    def hinge_strains(self, q: np.ndarray, fr: TrialFrames):
        """(kappa1, kappa2, tau) of every hinge; tau without the natural twist.

        Read from the springs' own evaluation (its gradient discarded): a kernel of its own for the strains alone
        cost a first run ~0.2 s of compiling, for a model's start and the motor torque of each snapshot."""
        S = np.empty((self.net.n_hinges, 6))
        self._bend_twist(q, fr, S, np.empty((self.net.n_hinges, 3)), np.zeros(self.ndof), None)
        return S[:, 3].copy(), S[:, 4].copy(), S[:, 5].copy()

    def hinge_moments(self, q: np.ndarray, fr: TrialFrames, twist_hinge: int = -1,
                      twist_offset: float = 0.0) -> np.ndarray:
        """(H, 3): every hinge's bending moments and twisting moment w_i = k_i (s_i - s_i_bar) (the energy's
        derivative w.r.t. each strain; hinge ``twist_hinge``'s natural twist shifted by ``twist_offset``), read
        from the springs' own evaluation like :meth:`hinge_strains`."""
        W = np.empty((self.net.n_hinges, 3))
        self._bend_twist(q, fr, np.empty((self.net.n_hinges, 6)), W, np.zeros(self.ndof), None, twist_hinge,
                         twist_offset)
        return W

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
        net = self.net
        _stretch(fr.t, fr.length, net.edge_rest_length, net.EA, self.stretch_dofs, self.stretch_slots, r,
                 J if want else np.empty(0), want)
        self._bend_twist(q, fr, self._strains, self._moments, r, J, twist_hinge, twist_offset)

    def _bend_twist(self, q, fr: TrialFrames, S: np.ndarray, W: np.ndarray, r: np.ndarray, J: np.ndarray | None,
                    twist_hinge: int = -1, twist_offset: float = 0.0) -> None:
        want = J is not None
        net = self.net
        _bend_twist_local(self.positions(q), q[3 * self.n_nodes:], fr.d1, fr.d2, fr.ref_twist, net.hinge_nodes,
                          net.hinge_edges, self.sign, self.beta, self.kappa_bar, self.tau_bar, self.k_bend,
                          self.k_twist, twist_hinge, twist_offset, S, W, self._grad, self._Hs, want)
        _bend_twist_global(fr.t, fr.t_committed, fr.length, net.hinge_edges, self.sign, self.hinge_dofs,
                           self.hinge_slots, self._grad, self._Hs, r, J if want else np.empty(0), want)
