"""Elastic energies of the rod network: stretching, bending and twisting, compiled, over all springs at once.

Paper equations: stretch Eq. (stretch, stretchingEnergy), curvature binormal Eq. (curvature), material curvatures
Eq. (BendingCurvature1/2), bending energy Eq. (bendingEnergy), twist and twisting energy Eq. (twistingEnergy).
Derivative formulas follow Bergou et al. (2008, 2010) and Jawed et al. (2018, "A primer on the kinematics of
discrete elastic rods"), written for a hinge whose edges may run against the traversal direction (sign s): such
an edge enters with tangent -t, reference frame (d1, -d2) and twist angle -theta.

A bend-twist hinge goes through small compiled stages, each one formula of the energy's chain rule:

    _hinge_kinematics   edge vectors, material frames, curvature binormal -> strains (kappa1, kappa2, tau)
    _strain_gradients   d(strain)/d(local DOFs), local DOFs [x_a, x_b, x_c, theta_ea, theta_eb]
    _strain_hessian     sum_i w_i d2(strain_i) with the weights w_i = k_i (s_i - s_i_bar)
    _edge_holonomy      the reference frame's spin under transport (exactness away from the committed frames)
    _change_variables   theta -> theta + Omega(x) applied to gradient and Hessian
    _scatter            into the residual vector and the CSC data array through slots built once

and ``_bend_twist`` runs them for every hinge. Energy, gradient and Hessian come from the same stages, so the
finite-difference tests check the code that runs.
"""
from __future__ import annotations

import math
from collections import namedtuple

import numpy as np
from numba import njit

from .frames import EdgeFrames, TrialFrames, cross3, material3, trial_frames
from .network import RodNetwork

#: the springs of all hinges, as one argument of the compiled stages
Hinges = namedtuple("Hinges", "nodes edges sign beta kappa_bar tau_bar k_bend k_twist dofs slots")
#: the trial frames, as one argument of the compiled stages
Frames = namedtuple("Frames", "t t_committed length d1 d2 ref_twist")


def _frames_tuple(fr: TrialFrames) -> Frames:
    return Frames(fr.t, fr.t_committed, fr.length, fr.d1, fr.d2, fr.ref_twist)


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
@njit(cache=True)
def _hinge_kinematics(x, theta, fr, hs, h, V):
    """Strains of hinge h. Fills V (7, 3) with te, tf, m1a, m2a, m1b, m2b, kb; returns (ne, nf, chi, k1, k2, tau)
    where tau is the twist without the natural twist."""
    a, b, c = hs.nodes[h, 0], hs.nodes[h, 1], hs.nodes[h, 2]
    ea, eb = hs.edges[h, 0], hs.edges[h, 1]
    sa, sb = hs.sign[h, 0], hs.sign[h, 1]
    ne = 0.0
    nf = 0.0
    for i in range(3):
        V[0, i] = x[b, i] - x[a, i]
        V[1, i] = x[c, i] - x[b, i]
        ne += V[0, i] * V[0, i]
        nf += V[1, i] * V[1, i]
    ne = math.sqrt(ne)
    nf = math.sqrt(nf)
    for i in range(3):
        V[0, i] /= ne
        V[1, i] /= nf
    tha = sa * theta[ea] + hs.beta[h]
    thb = sb * theta[eb]
    d1, d2 = fr.d1, fr.d2
    (V[2, 0], V[2, 1], V[2, 2], V[3, 0], V[3, 1], V[3, 2]) = material3(
        d1[ea, 0], d1[ea, 1], d1[ea, 2], sa * d2[ea, 0], sa * d2[ea, 1], sa * d2[ea, 2], tha)
    (V[4, 0], V[4, 1], V[4, 2], V[5, 0], V[5, 1], V[5, 2]) = material3(
        d1[eb, 0], d1[eb, 1], d1[eb, 2], sb * d2[eb, 0], sb * d2[eb, 1], sb * d2[eb, 2], thb)
    chi = 1.0 + V[0, 0] * V[1, 0] + V[0, 1] * V[1, 1] + V[0, 2] * V[1, 2]
    x0, x1, x2 = cross3(V[0, 0], V[0, 1], V[0, 2], V[1, 0], V[1, 1], V[1, 2])
    V[6, 0], V[6, 1], V[6, 2] = 2.0 * x0 / chi, 2.0 * x1 / chi, 2.0 * x2 / chi
    k1 = 0.0
    k2 = 0.0
    for i in range(3):
        k1 += 0.5 * V[6, i] * (V[3, i] + V[5, i])
        k2 -= 0.5 * V[6, i] * (V[2, i] + V[4, i])
    tau = thb - tha + fr.ref_twist[h]
    return ne, nf, chi, k1, k2, tau


@njit(cache=True)
def _strain_gradients(V, ne, nf, chi, k1, k2, G):
    """G (3, 11): gradients of kappa1, kappa2, tau w.r.t. [x_a, x_b, x_c, theta_a, theta_b] (edges unsigned)."""
    ic = 1.0 / chi
    tt0, tt1, tt2 = (V[0, 0] + V[1, 0]) * ic, (V[0, 1] + V[1, 1]) * ic, (V[0, 2] + V[1, 2]) * ic
    d10, d11, d12 = (V[2, 0] + V[4, 0]) * ic, (V[2, 1] + V[4, 1]) * ic, (V[2, 2] + V[4, 2]) * ic
    d20, d21, d22 = (V[3, 0] + V[5, 0]) * ic, (V[3, 1] + V[5, 1]) * ic, (V[3, 2] + V[5, 2]) * ic
    te0, te1, te2 = V[0, 0], V[0, 1], V[0, 2]
    tf0, tf1, tf2 = V[1, 0], V[1, 1], V[1, 2]
    A = cross3(tf0, tf1, tf2, d20, d21, d22)
    B = cross3(te0, te1, te2, d20, d21, d22)
    C = cross3(tf0, tf1, tf2, d10, d11, d12)
    E = cross3(te0, te1, te2, d10, d11, d12)
    ine, inf = 1.0 / ne, 1.0 / nf
    tt = (tt0, tt1, tt2)
    for i in range(3):
        de0 = (-k1 * tt[i] + A[i]) * ine      # edge-space gradients: e then f, per strain
        df0 = (-k1 * tt[i] - B[i]) * inf
        de1 = (-k2 * tt[i] - C[i]) * ine
        df1 = (-k2 * tt[i] + E[i]) * inf
        de2 = 0.5 * V[6, i] * ine
        df2 = 0.5 * V[6, i] * inf
        # node map: x_a = -e, x_b = e - f, x_c = f
        G[0, i], G[0, 3 + i], G[0, 6 + i] = -de0, de0 - df0, df0
        G[1, i], G[1, 3 + i], G[1, 6 + i] = -de1, de1 - df1, df1
        G[2, i], G[2, 3 + i], G[2, 6 + i] = -de2, de2 - df2, df2
    for jj in range(2):
        r1 = 2 + 2 * jj
        G[0, 9 + jj] = -0.5 * (V[6, 0] * V[r1, 0] + V[6, 1] * V[r1, 1] + V[6, 2] * V[r1, 2])
        G[1, 9 + jj] = -0.5 * (V[6, 0] * V[r1 + 1, 0] + V[6, 1] * V[r1 + 1, 1] + V[6, 2] * V[r1 + 1, 2])
    G[2, 9], G[2, 10] = -1.0, 1.0


@njit(cache=True)
def _skew(v, i, j):
    """Entry (i, j) of [v]x (the matrix with [v]x u = v x u): -eps_ijk v_k."""
    if i == j:
        return 0.0
    k = 3 - i - j
    return -v[k] if (j - i) % 3 == 1 else v[k]


@njit(cache=True)
def _strain_hessian(V, ne, nf, chi, k1, k2, w1, w2, wt, H, S, W):
    """H (11, 11) = w1 d2 kappa1 + w2 d2 kappa2 + wt d2 tau (local DOFs, edges unsigned).

    The weighted curvature Hessians are linear in the frame vectors, so they are formed directly from
    K = w1 k1 + w2 k2 and Dv = w1 d2~ - w2 d1~ instead of one Hessian per strain. S is (3, 3, 3) scratch for the
    edge-space blocks S_ee, S_ff, S_ef; W (4, 3) scratch.
    """
    ic = 1.0 / chi
    te = V[0]
    tf = V[1]
    kb = V[6]
    tt, Dv, Ma, Mb = W[0], W[1], W[2], W[3]
    for i in range(3):
        tt[i] = (te[i] + tf[i]) * ic
        Dv[i] = w1 * (V[3, i] + V[5, i]) * ic - w2 * (V[2, i] + V[4, i]) * ic
        Ma[i] = w1 * V[3, i] - w2 * V[2, i]
        Mb[i] = w1 * V[5, i] - w2 * V[4, i]
    A = cross3(tf[0], tf[1], tf[2], Dv[0], Dv[1], Dv[2])
    B = cross3(te[0], te[1], te[2], Dv[0], Dv[1], Dv[2])
    K = w1 * k1 + w2 * k2
    ine, inf = 1.0 / ne, 1.0 / nf
    for i in range(3):
        for j in range(3):
            dij = 1.0 if i == j else 0.0
            Kttt = 2.0 * K * tt[i] * tt[j]
            S[0, i, j] = ine * ine * (
                Kttt - (A[i] * tt[j] + tt[i] * A[j]) - K * ic * (dij - te[i] * te[j])
                + 0.25 * (kb[i] * Ma[j] + Ma[i] * kb[j])
                - 0.25 * wt * (kb[i] * (te[j] + tt[j]) + (te[i] + tt[i]) * kb[j]))
            S[1, i, j] = inf * inf * (
                Kttt + (B[i] * tt[j] + tt[i] * B[j]) - K * ic * (dij - tf[i] * tf[j])
                + 0.25 * (kb[i] * Mb[j] + Mb[i] * kb[j])
                - 0.25 * wt * (kb[i] * (tf[j] + tt[j]) + (tf[i] + tt[i]) * kb[j]))
            S[2, i, j] = ine * inf * (
                -K * ic * (dij + te[i] * tf[j]) + Kttt - A[i] * tt[j] + tt[i] * B[j] - _skew(Dv, i, j)
                + wt * (ic * _skew(te, i, j) - 0.5 * kb[i] * tt[j]))
    # node map x_a = -e, x_b = e - f, x_c = f on the 3x3 blocks (S_fe = S_ef^T)
    for i in range(3):
        for j in range(3):
            see, sff, sef, sfe = S[0, i, j], S[1, i, j], S[2, i, j], S[2, j, i]
            H[i, j] = see
            H[i, 3 + j] = -see + sef
            H[i, 6 + j] = -sef
            H[3 + i, 3 + j] = see - sef - sfe + sff
            H[3 + i, 6 + j] = sef - sff
            H[6 + i, 6 + j] = sff
            H[3 + j, i] = H[i, 3 + j]
            H[6 + j, i] = H[i, 6 + j]
            H[6 + j, 3 + i] = H[3 + i, 6 + j]
    # position-theta: theta_a rotates (m1a, m2a), theta_b (m1b, m2b)
    for jj in range(2):
        r1 = 2 + 2 * jj
        kbm1 = kb[0] * V[r1, 0] + kb[1] * V[r1, 1] + kb[2] * V[r1, 2]
        kbm2 = kb[0] * V[r1 + 1, 0] + kb[1] * V[r1 + 1, 1] + kb[2] * V[r1 + 1, 2]
        s_ = 0.5 * (w1 * kbm1 + w2 * kbm2)
        wm0 = w1 * V[r1, 0] + w2 * V[r1 + 1, 0]
        wm1 = w1 * V[r1, 1] + w2 * V[r1 + 1, 1]
        wm2 = w1 * V[r1, 2] + w2 * V[r1 + 1, 2]
        f = cross3(tf[0], tf[1], tf[2], wm0, wm1, wm2)
        g = cross3(te[0], te[1], te[2], wm0, wm1, wm2)
        for i in range(3):
            se = ine * (s_ * tt[i] - ic * f[i])
            sf = inf * (s_ * tt[i] + ic * g[i])
            H[i, 9 + jj] = -se
            H[3 + i, 9 + jj] = se - sf
            H[6 + i, 9 + jj] = sf
            H[9 + jj, i] = -se
            H[9 + jj, 3 + i] = se - sf
            H[9 + jj, 6 + i] = sf
        # theta-theta: kappa is linear in m_a + m_b (no cross term), tau is linear in theta
        H[9 + jj, 9 + jj] = 0.5 * (w2 * kbm1 - w1 * kbm2)
    H[9, 10] = 0.0
    H[10, 9] = 0.0


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
        c = c0 * t0 + c1 * t1 + c2 * t2
        w = cross3(c0, c1, c2, t0, t1, t2)
        le = length[k]
        gt = (-w[0] / (1.0 + c), -w[1] / (1.0 + c), -w[2] / (1.0 + c))
        for i in range(3):
            g[k, i] = gt[i] / le
        if not want_hessian:
            continue
        s = 1.0 / (2.0 * (1.0 + c) ** 2)
        up = (c0 - c * t0, c1 - c * t1, c2 - c * t2)
        tv = (t0, t1, t2)
        il2 = 1.0 / (le * le)
        for i in range(3):
            for j in range(3):
                Hh[k, i, j] = (s * (w[i] * up[j] + up[i] * w[j]) - (tv[i] * gt[j] + gt[i] * tv[j])) * il2


@njit(cache=True)
def _change_variables(grad, H, Vh, hhA, hhB, want_hessian, Ht):
    """Apply y_theta = theta + Omega(x): gradient g <- g + g_theta dOmega/dx, and
    H <- T^T H T + sum_k g_theta_k d2Omega_k. Vh (2, 11): dOmega of the two edges in local DOFs; Ht (2, 11)
    scratch."""
    gA, gB = grad[9], grad[10]
    if want_hessian:
        h99, h9a, ha9, haa = H[9, 9], H[9, 10], H[10, 9], H[10, 10]
        for j in range(11):
            Ht[0, j] = H[9, j]
            Ht[1, j] = H[10, j]
        Ht0 = Ht[0]
        Ht1 = Ht[1]
        for i in range(11):
            for j in range(11):
                H[i, j] += (Vh[0, i] * Ht0[j] + Vh[1, i] * Ht1[j] + Ht0[i] * Vh[0, j] + Ht1[i] * Vh[1, j]
                            + Vh[0, i] * (h99 * Vh[0, j] + h9a * Vh[1, j])
                            + Vh[1, i] * (ha9 * Vh[0, j] + haa * Vh[1, j]))
        # an edge's block [[B, -B], [-B, B]] is unchanged by swapping its ends, so the sign does not enter
        for i in range(3):
            for j in range(3):
                hA = gA * hhA[i, j]
                hB = gB * hhB[i, j]
                H[i, j] += hA
                H[3 + i, 3 + j] += hA + hB
                H[i, 3 + j] -= hA
                H[3 + i, j] -= hA
                H[6 + i, 6 + j] += hB
                H[3 + i, 6 + j] -= hB
                H[6 + i, 3 + j] -= hB
    for j in range(9):
        grad[j] += gA * Vh[0, j] + gB * Vh[1, j]


@njit(cache=True)
def _scatter(dofs, slots, grad, H, r, J, want_hessian):
    for j in range(grad.shape[0]):
        r[dofs[j]] += grad[j]
    if want_hessian:
        for i in range(H.shape[0]):
            for j in range(H.shape[1]):
                J[slots[i, j]] += H[i, j]


@njit(cache=True)
def _bend_twist(x, theta, fr, hs, twist_hinge, twist_offset, r, J, want_hessian):
    """Bend + twist forces of every hinge into r (and their Hessian into J). The natural twist of hinge
    ``twist_hinge`` is shifted by ``twist_offset`` (the motor, paper Eq. SpecifyTheta)."""
    ne_ = fr.t.shape[0]
    hg = np.empty((ne_, 3))
    hh = np.empty((ne_, 3, 3))
    _edge_holonomy(fr.t, fr.t_committed, fr.length, hg, hh, want_hessian)
    V = np.empty((7, 3))
    G = np.empty((3, 11))
    grad = np.empty(11)
    H = np.empty((11, 11))
    S = np.empty((3, 3, 3))
    W = np.empty((4, 3))
    Ht = np.empty((2, 11))
    Vh = np.zeros((2, 11))
    sgn = np.ones(11)
    for h in range(hs.nodes.shape[0]):
        ne, nf, chi, k1, k2, tau = _hinge_kinematics(x, theta, fr, hs, h, V)
        tau_bar = hs.tau_bar[h] + (twist_offset if h == twist_hinge else 0.0)
        kb, kt = hs.k_bend[h], hs.k_twist[h]
        w1 = kb * (k1 - hs.kappa_bar[h, 0])
        w2 = kb * (k2 - hs.kappa_bar[h, 1])
        wt = kt * (tau - tau_bar)
        _strain_gradients(V, ne, nf, chi, k1, k2, G)
        sa, sb = hs.sign[h, 0], hs.sign[h, 1]
        sgn[9], sgn[10] = sa, sb
        for j in range(11):
            grad[j] = (w1 * G[0, j] + w2 * G[1, j] + wt * G[2, j]) * sgn[j]
        if want_hessian:
            _strain_hessian(V, ne, nf, chi, k1, k2, w1, w2, wt, H, S, W)
            for i in range(11):
                for j in range(11):      # plus the Gauss-Newton part sum_i k_i grad(s_i) grad(s_i)^T
                    H[i, j] = (H[i, j] + kb * (G[0, i] * G[0, j] + G[1, i] * G[1, j])
                               + kt * G[2, i] * G[2, j]) * sgn[i] * sgn[j]
        ea, eb = hs.edges[h, 0], hs.edges[h, 1]
        for i in range(3):      # edge a joins local nodes 0-1, edge b nodes 1-2; a reversed edge flips the sign
            Vh[0, i], Vh[0, 3 + i] = -sa * hg[ea, i], sa * hg[ea, i]
            Vh[1, 3 + i], Vh[1, 6 + i] = -sb * hg[eb, i], sb * hg[eb, i]
        _change_variables(grad, H, Vh, hh[ea], hh[eb], want_hessian, Ht)
        _scatter(hs.dofs[h], hs.slots[h], grad, H, r, J, want_hessian)


@njit(cache=True)
def _hinge_strains(x, theta, fr, hs, k1s, k2s, taus):
    V = np.empty((7, 3))
    for h in range(hs.nodes.shape[0]):
        _, _, _, k1s[h], k2s[h], taus[h] = _hinge_kinematics(x, theta, fr, hs, h, V)


@njit(cache=True)
def _bend_twist_energy(x, theta, fr, hs, twist_hinge, twist_offset):
    V = np.empty((7, 3))
    E = 0.0
    for h in range(hs.nodes.shape[0]):
        _, _, _, k1, k2, tau = _hinge_kinematics(x, theta, fr, hs, h, V)
        tau_bar = hs.tau_bar[h] + (twist_offset if h == twist_hinge else 0.0)
        dk1, dk2 = k1 - hs.kappa_bar[h, 0], k2 - hs.kappa_bar[h, 1]
        E += 0.5 * hs.k_bend[h] * (dk1 * dk1 + dk2 * dk2) + 0.5 * hs.k_twist[h] * (tau - tau_bar) ** 2
    return E


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

    @property
    def hinges(self) -> Hinges:
        return Hinges(self.net.hinge_nodes, self.net.hinge_edges, self.sign, self.beta, self.kappa_bar,
                      self.tau_bar, self.k_bend, self.k_twist, self.hinge_dofs, self.hinge_slots)

    def set_slots(self, stretch_slots: np.ndarray, hinge_slots: np.ndarray) -> None:
        """Positions in the CSC data array of every stretch (6x6) and hinge (11x11) Jacobian entry."""
        self.stretch_slots = np.ascontiguousarray(stretch_slots.reshape(-1, 6, 6))
        self.hinge_slots = np.ascontiguousarray(hinge_slots.reshape(-1, 11, 11))

    # ------------------------------------------------------------------ strains and energy
    def hinge_strains(self, q: np.ndarray, fr: TrialFrames):
        """(kappa1, kappa2, tau) of every hinge; tau without the natural twist."""
        H = self.net.n_hinges
        k1, k2, tau = np.empty(H), np.empty(H), np.empty(H)
        _hinge_strains(self.positions(q), q[3 * self.n_nodes:], _frames_tuple(fr), self.hinges, k1, k2, tau)
        return k1, k2, tau

    def stretch_strain(self, fr: TrialFrames) -> np.ndarray:
        return fr.length / self.net.edge_rest_length - 1.0

    def energy(self, q: np.ndarray, fr: TrialFrames, twist_hinge: int = -1, twist_offset: float = 0.0) -> float:
        return float(_stretch_energy(fr.length, self.net.edge_rest_length, self.net.EA)
                     + _bend_twist_energy(self.positions(q), q[3 * self.n_nodes:], _frames_tuple(fr), self.hinges,
                                          twist_hinge, twist_offset))

    # ------------------------------------------------------------------ into the global system
    def accumulate(self, q: np.ndarray, fr: TrialFrames, r: np.ndarray, J: np.ndarray | None,
                   twist_hinge: int = -1, twist_offset: float = 0.0) -> None:
        """Add the elastic gradient to r and, if J (CSC data array) is given, the Hessian to J."""
        want = J is not None
        d = J if want else np.empty(0)
        net = self.net
        _stretch(fr.t, fr.length, net.edge_rest_length, net.EA, self.stretch_dofs, self.stretch_slots, r, d, want)
        _bend_twist(self.positions(q), q[3 * self.n_nodes:], _frames_tuple(fr), self.hinges, twist_hinge,
                    twist_offset, r, d, want)
