"""Elastic energies of the rod network: stretching, bending and twisting, vectorised over all springs.

Each spring type computes its strains for every spring at once, their first and second derivatives with respect
to the spring's local DOFs (6 for a stretching spring, 11 for a bend-twist hinge), and from those the energy
gradient and Hessian blocks by the chain rule. The model scatters the blocks into the global vector / sparse
matrix through index arrays built once (:mod:`flagbot_sim.physics.assembly`).

Paper equations: stretch Eq. (stretch, stretchingEnergy), curvature binormal Eq. (curvature), material curvatures
Eq. (BendingCurvature1/2), bending energy Eq. (bendingEnergy), twist and twisting energy Eq. (twistingEnergy).
Derivative formulas follow Bergou et al. (2008, 2010) and Jawed et al. (2018, "A primer on the kinematics of
discrete elastic rods"), written here for a hinge whose edges may run against the traversal direction (sign s):
such an edge enters with tangent -t, reference frame (d1, -d2) and twist angle -theta.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import kernels
from .frames import EdgeFrames, cross, material_frames, normalize, parallel_transport, rowdot, signed_angle, unwrap_to
from .network import RodNetwork

# node <- edge map of a hinge: x_a = -e, x_b = e - f, x_c = f (e = x_b - x_a, f = x_c - x_b)
_NODE_MAP = np.array([[-1.0, 0.0], [1.0, -1.0], [0.0, 1.0]])
_EYE = np.eye(3)


def _outer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[:, :, None] * b[:, None, :]


def _skew(v: np.ndarray) -> np.ndarray:
    """[v]x such that [v]x @ u = v x u, row-wise."""
    z = np.zeros(len(v))
    return np.stack([np.stack([z, -v[:, 2], v[:, 1]], -1),
                     np.stack([v[:, 2], z, -v[:, 0]], -1),
                     np.stack([-v[:, 1], v[:, 0], z], -1)], 1)


def _sym(a: np.ndarray) -> np.ndarray:
    return a + np.swapaxes(a, -1, -2)


@dataclass
class TrialFrames:
    """Frames of a trial configuration: tangents, edge lengths, transported reference frames, reference twist."""
    t: np.ndarray
    length: np.ndarray
    d1: np.ndarray
    d2: np.ndarray
    ref_twist: np.ndarray
    t_committed: np.ndarray   # tangents the reference frames were transported from


def holonomy_terms(fr: TrialFrames, want_hessian: bool):
    """Gradient (Ne, 6) and Hessian (Ne, 6, 6) of each edge's holonomy spin Omega w.r.t. its two end nodes.

    The reference frame used at a trial configuration is d = P(t_c -> t) d_c (one transport from the committed
    tangent t_c). The DER derivative formulas differentiate as if the frame moved by the *minimal* transport from
    the current tangent t. The two differ by a spin about t equal to the solid angle of the geodesic triangle
    (t_c, t, t'), which acts exactly like an extra twist angle: E(x, theta) = E_min(x, theta + Omega(x)), with
    Omega(t) = 0,  dOmega/dt' = -w / (1 + c),  d2Omega/dt'2 = (w u^T + u w^T) / (2 (1 + c)^2)
    at t' = t, where w = t_c x t, u = t_c + t, c = t_c . t. Adding these terms makes the elastic force the exact
    gradient of the energy at every Newton iterate (not only at the committed state) and the Hessian its exact
    Jacobian, which keeps Newton quadratic when parts of the robot turn quickly.
    """
    t, tc, le = fr.t, fr.t_committed, fr.length
    c = rowdot(tc, t)
    w = cross(tc, t)
    g_t = -w / (1.0 + c)[:, None]                      # dOmega/dt' (already normal to t)
    g_e = g_t / le[:, None]
    grad = np.concatenate([-g_e, g_e], axis=1)          # tail node = -e, head node = +e
    if not want_hessian:
        return grad, None
    u = tc + t
    H_t = _sym(_outer(w, u)) / (2.0 * (1.0 + c) ** 2)[:, None, None]
    P = _EYE - _outer(t, t)
    H_e = (P @ H_t @ P - _sym(_outer(t, g_t))) / (le ** 2)[:, None, None]
    hess = np.empty((len(t), 6, 6))
    hess[:, :3, :3] = H_e
    hess[:, 3:, 3:] = H_e
    hess[:, :3, 3:] = -H_e
    hess[:, 3:, :3] = -H_e
    return grad, hess


class ElasticModel:
    """Stretching + bend-twist springs of a :class:`RodNetwork`."""

    def __init__(self, net: RodNetwork):
        self.net = net
        N = net.n_nodes
        ndof = net.ndof
        self.ndof = ndof
        self.n_nodes = N
        E = net.edges
        # ---- stretching springs: DOFs of both end nodes
        self.stretch_dofs = np.concatenate([net.node_dofs(E[:, 0]), net.node_dofs(E[:, 1])], axis=1)  # (Ne, 6)
        # ---- bend-twist hinges: [x_a, x_b, x_c, theta_ea, theta_eb]
        hn, he = net.hinge_nodes, net.hinge_edges
        self.hinge_dofs = np.concatenate([net.node_dofs(hn[:, 0]), net.node_dofs(hn[:, 1]),
                                          net.node_dofs(hn[:, 2]), net.edge_dof(he)], axis=1)  # (H, 11)
        self.sign = net.hinge_sign
        self.sign11 = np.concatenate([np.ones((len(hn), 9)), self.sign], axis=1)
        self.k_bend = net.EI / net.voronoi
        self.k_twist = net.GJ / net.voronoi
        # ---- rest strains from the undeformed configuration with theta = 0
        q0 = net.initial_q()
        x0 = q0[: 3 * N].reshape(N, 3)
        t0, _ = normalize(x0[E[:, 1]] - x0[E[:, 0]])
        self.frames0 = EdgeFrames(t0)
        self.frames0.ref_twist = np.zeros(net.n_hinges)
        self.beta = np.zeros(net.n_hinges)
        tf = self.trial_frames(q0, self.frames0)
        self.frames0.ref_twist = tf.ref_twist.copy()
        # Frame offset per hinge: turn edge a's frame by its rest reference twist so that the two material frames
        # a hinge averages are aligned at rest. Without it, a 90-degree hinge whose frames start a half turn
        # apart has m_a + m_b = 0: its curvature loses a direction and the "rigid" plate flops about the joint.
        self.beta = tf.ref_twist.copy()
        k1, k2, tau = self.hinge_strains(q0, tf)
        self.kappa_bar = np.stack([k1, k2], axis=1)
        self.tau_bar0 = tau.copy()
        self.tau_bar = tau.copy()     # the motor moves entries of this (natural twist)

    # ------------------------------------------------------------------ frames
    def positions(self, q: np.ndarray) -> np.ndarray:
        return q[: 3 * self.n_nodes].reshape(self.n_nodes, 3)

    #: compiled kernels when numba is available (set False on an instance to use the numpy reference)
    use_kernels = kernels.AVAILABLE

    def trial_frames(self, q: np.ndarray, committed: EdgeFrames) -> TrialFrames:
        if self.use_kernels:
            Ne, H = self.net.n_edges, self.net.n_hinges
            t, length = np.empty((Ne, 3)), np.empty(Ne)
            d1, d2, rt = np.empty((Ne, 3)), np.empty((Ne, 3)), np.empty(H)
            kernels.frames(self.positions(q), self.net.edges, committed.d1, committed.t, self.net.hinge_edges,
                           self.sign, committed.ref_twist, t, length, d1, d2, rt)
            return TrialFrames(t=t, length=length, d1=d1, d2=d2, ref_twist=rt, t_committed=committed.t)
        return self.trial_frames_numpy(q, committed)

    def trial_frames_numpy(self, q: np.ndarray, committed: EdgeFrames) -> TrialFrames:
        x = self.positions(q)
        E = self.net.edges
        t, length = normalize(x[E[:, 1]] - x[E[:, 0]])
        d1, d2 = committed.transported(t)
        he, s = self.net.hinge_edges, self.sign
        ta = s[:, 0:1] * t[he[:, 0]]
        tb = s[:, 1:2] * t[he[:, 1]]
        rt = signed_angle(parallel_transport(d1[he[:, 0]], ta, tb), d1[he[:, 1]], tb)
        rt = unwrap_to(rt, committed.ref_twist)
        return TrialFrames(t=t, length=length, d1=d1, d2=d2, ref_twist=rt, t_committed=committed.t)

    # ------------------------------------------------------------------ strains
    def _hinge_geometry(self, q: np.ndarray, fr: TrialFrames):
        x = self.positions(q)
        theta = q[3 * self.n_nodes:]
        hn, he, s = self.net.hinge_nodes, self.net.hinge_edges, self.sign
        e = x[hn[:, 1]] - x[hn[:, 0]]
        f = x[hn[:, 2]] - x[hn[:, 1]]
        ne = np.linalg.norm(e, axis=1)
        nf = np.linalg.norm(f, axis=1)
        te = e / ne[:, None]
        tf = f / nf[:, None]
        ea, eb = he[:, 0], he[:, 1]
        m1a, m2a = material_frames(fr.d1[ea], s[:, 0:1] * fr.d2[ea], s[:, 0] * theta[ea] + self.beta)
        m1b, m2b = material_frames(fr.d1[eb], s[:, 1:2] * fr.d2[eb], s[:, 1] * theta[eb])
        chi = 1.0 + rowdot(te, tf)
        kb = 2.0 * cross(te, tf) / chi[:, None]
        k1 = 0.5 * rowdot(kb, m2a + m2b)
        k2 = -0.5 * rowdot(kb, m1a + m1b)
        tau = s[:, 1] * theta[eb] - s[:, 0] * theta[ea] - self.beta + fr.ref_twist
        return dict(ne=ne, nf=nf, te=te, tf=tf, m1a=m1a, m2a=m2a, m1b=m1b, m2b=m2b, chi=chi, kb=kb,
                    k1=k1, k2=k2, tau=tau)

    def hinge_strains(self, q: np.ndarray, fr: TrialFrames):
        g = self._hinge_geometry(q, fr)
        return g["k1"], g["k2"], g["tau"]

    def stretch_strain(self, fr: TrialFrames) -> np.ndarray:
        return fr.length / self.net.edge_rest_length - 1.0

    # ------------------------------------------------------------------ energy
    def energy(self, q: np.ndarray, fr: TrialFrames) -> float:
        eps = self.stretch_strain(fr)
        Es = 0.5 * np.sum(self.net.EA * eps ** 2 * self.net.edge_rest_length)
        k1, k2, tau = self.hinge_strains(q, fr)
        dk = np.stack([k1, k2], 1) - self.kappa_bar
        Eb = 0.5 * np.sum(self.k_bend * np.sum(dk ** 2, axis=1))
        Et = 0.5 * np.sum(self.k_twist * (tau - self.tau_bar) ** 2)
        return float(Es + Eb + Et)

    # ------------------------------------------------------------------ into the global system
    def set_slots(self, stretch_slots: np.ndarray, hinge_slots: np.ndarray) -> None:
        """Positions in the CSC data array of every stretch (6x6) and hinge (11x11) Jacobian entry."""
        self.stretch_slots = np.ascontiguousarray(stretch_slots.reshape(-1, 6, 6))
        self.hinge_slots = np.ascontiguousarray(hinge_slots.reshape(-1, 11, 11))

    def accumulate(self, q: np.ndarray, fr: TrialFrames, r: np.ndarray, data: np.ndarray | None) -> None:
        """Add the elastic gradient to r and, if data is given, the Hessian to the CSC data array."""
        want = data is not None
        if self.use_kernels:
            d = data if want else np.empty(0)
            net = self.net
            kernels.stretch(fr.t, fr.length, net.edge_rest_length, net.EA, self.stretch_dofs, self.stretch_slots,
                            r, d, want)
            kernels.bend_twist(self.positions(q), q[3 * self.n_nodes:], fr.t, fr.t_committed, fr.length, fr.d1,
                               fr.d2, fr.ref_twist, net.hinge_nodes, net.hinge_edges, self.sign, self.beta,
                               self.kappa_bar, self.tau_bar, self.k_bend, self.k_twist, self.hinge_dofs,
                               self.hinge_slots, r, d, want)
            return
        gs, hs = self.stretch_terms(fr, want)
        gh, hh = self.hinge_terms(q, fr, want)
        r += np.bincount(np.concatenate([self.stretch_dofs.ravel(), self.hinge_dofs.ravel()]),
                         weights=np.concatenate([gs.ravel(), gh.ravel()]), minlength=len(r))
        if want:
            data += np.bincount(np.concatenate([self.stretch_slots.ravel(), self.hinge_slots.ravel()]),
                                weights=np.concatenate([hs.ravel(), hh.ravel()]), minlength=len(data))

    # ------------------------------------------------------------------ gradient / Hessian
    def stretch_terms(self, fr: TrialFrames, want_hessian: bool):
        EA, L0 = self.net.EA, self.net.edge_rest_length
        t, le = fr.t, fr.length
        g_e = (EA * (le / L0 - 1.0))[:, None] * t           # dE/de
        grad = np.concatenate([-g_e, g_e], axis=1)          # (Ne, 6)
        if not want_hessian:
            return grad, None
        tt = _outer(t, t)
        K = (EA / L0)[:, None, None] * tt + (EA * (1.0 / L0 - 1.0 / le))[:, None, None] * (_EYE - tt)
        hess = np.empty((len(t), 6, 6))
        hess[:, :3, :3] = K
        hess[:, 3:, 3:] = K
        hess[:, :3, 3:] = -K
        hess[:, 3:, :3] = -K
        return grad, hess

    def hinge_terms(self, q: np.ndarray, fr: TrialFrames, want_hessian: bool):
        """Gradient (H, 11) and Hessian (H, 11, 11) of the bend + twist energy of every hinge.

        Local DOF order: [x_a, x_b, x_c, theta_ea, theta_eb]. The energy's second derivative is
        sum_i k_i (grad s_i)(grad s_i)^T + sum_i w_i hess s_i over the strains s = (kappa1, kappa2, tau), with
        w_i = k_i (s_i - s_i_bar). The w-weighted curvature Hessians are linear in the frame vectors, so they are
        formed directly from K = w1 k1 + w2 k2 and Dv = w1 d2~ - w2 d1~ instead of one Hessian per strain.
        """
        g = self._hinge_geometry(q, fr)
        ne, nf, te, tf, chi, kb = g["ne"], g["nf"], g["te"], g["tf"], g["chi"], g["kb"]
        m1a, m2a, m1b, m2b, k1, k2, tau = g["m1a"], g["m2a"], g["m1b"], g["m2b"], g["k1"], g["k2"], g["tau"]
        H = len(ne)
        ic = 1.0 / chi
        tt = (te + tf) * ic[:, None]
        d1t = (m1a + m1b) * ic[:, None]
        d2t = (m2a + m2b) * ic[:, None]
        ine, inf = 1.0 / ne, 1.0 / nf
        kbm = np.stack([rowdot(kb, m1a), rowdot(kb, m1b), rowdot(kb, m2a), rowdot(kb, m2b)], 1)
        # strain gradients in edge space, stacked (kappa1, kappa2, tau): (3, H, 3) for e and f, (3, H, 2) theta
        De = np.stack([-k1[:, None] * tt + cross(tf, d2t), -k2[:, None] * tt - cross(tf, d1t), 0.5 * kb]) \
            * ine[None, :, None]
        Df = np.stack([-k1[:, None] * tt - cross(te, d2t), -k2[:, None] * tt + cross(te, d1t), 0.5 * kb]) \
            * inf[None, :, None]
        Dth = np.stack([-0.5 * kbm[:, 0:2], -0.5 * kbm[:, 2:4], np.tile([-1.0, 1.0], (H, 1))])
        G = np.empty((3, H, 11))                     # node map: x_a = -e, x_b = e - f, x_c = f
        G[:, :, 0:3] = -De
        G[:, :, 3:6] = De - Df
        G[:, :, 6:9] = Df
        G[:, :, 9:11] = Dth
        stiff = np.stack([self.k_bend, self.k_bend, self.k_twist])                  # (3, H)
        w = stiff * np.stack([k1 - self.kappa_bar[:, 0], k2 - self.kappa_bar[:, 1], tau - self.tau_bar])
        grad = np.einsum("sh,shj->hj", w, G) * self.sign11
        hg, hh = holonomy_terms(fr, want_hessian)
        V = self._embed_holonomy_gradient(hg)            # (H, 2, 11)
        g_theta = grad[:, 9:11].copy()
        grad += np.einsum("hk,hkj->hj", g_theta, V)
        if not want_hessian:
            return grad, None

        w1, w2, wt = w
        K = w1 * k1 + w2 * k2
        Dv = w1[:, None] * d2t - w2[:, None] * d1t
        A = cross(tf, Dv)
        B = cross(te, Dv)
        Ma = w1[:, None] * m2a - w2[:, None] * m1a
        Mb = w1[:, None] * m2b - w2[:, None] * m1b
        ne2, nf2, nenf = ine * ine, inf * inf, ine * inf
        Kttt = (2.0 * K)[:, None, None] * _outer(tt, tt)
        Kc = (K * ic)[:, None, None]
        W = lambda a: a[:, None, None]  # noqa: E731
        # position-position second derivatives in edge space (curvatures with weights, plus twist via ref twist)
        S_ee = W(ne2) * (Kttt - _sym(_outer(A, tt)) - Kc * (_EYE - _outer(te, te))
                         + 0.25 * _sym(_outer(kb, Ma)) - 0.25 * W(wt) * _sym(_outer(kb, te + tt)))
        S_ff = W(nf2) * (Kttt + _sym(_outer(B, tt)) - Kc * (_EYE - _outer(tf, tf))
                         + 0.25 * _sym(_outer(kb, Mb)) - 0.25 * W(wt) * _sym(_outer(kb, tf + tt)))
        S_ef = W(nenf) * (-Kc * (_EYE + _outer(te, tf)) + Kttt - _outer(A, tt) + _outer(tt, B) - _skew(Dv)
                          + W(wt) * (W(ic) * _skew(te) - 0.5 * _outer(kb, tt)))
        S_fe = np.swapaxes(S_ef, 1, 2)
        # position-theta: column j = theta_a, theta_b
        Sxt_e = np.empty((H, 3, 2))
        Sxt_f = np.empty((H, 3, 2))
        for j, (m1, m2) in enumerate(((m1a, m2a), (m1b, m2b))):
            s_ = 0.5 * (w1 * kbm[:, j] + w2 * kbm[:, 2 + j])
            wm = w1[:, None] * m1 + w2[:, None] * m2
            Sxt_e[:, :, j] = ine[:, None] * (s_[:, None] * tt - ic[:, None] * cross(tf, wm))
            Sxt_f[:, :, j] = inf[:, None] * (s_[:, None] * tt + ic[:, None] * cross(te, wm))

        hess = np.zeros((H, 11, 11))
        # node map on the 3x3 blocks: a = -e, b = e - f, c = f
        hess[:, 0:3, 0:3] = S_ee
        hess[:, 0:3, 3:6] = -S_ee + S_ef
        hess[:, 0:3, 6:9] = -S_ef
        hess[:, 3:6, 3:6] = S_ee - S_ef - S_fe + S_ff
        hess[:, 3:6, 6:9] = S_ef - S_ff
        hess[:, 6:9, 6:9] = S_ff
        hess[:, 3:6, 0:3] = np.swapaxes(hess[:, 0:3, 3:6], 1, 2)
        hess[:, 6:9, 0:3] = np.swapaxes(hess[:, 0:3, 6:9], 1, 2)
        hess[:, 6:9, 3:6] = np.swapaxes(hess[:, 3:6, 6:9], 1, 2)
        hess[:, 0:3, 9:11] = -Sxt_e
        hess[:, 3:6, 9:11] = Sxt_e - Sxt_f
        hess[:, 6:9, 9:11] = Sxt_f
        hess[:, 9:11, 0:9] = np.swapaxes(hess[:, 0:9, 9:11], 1, 2)
        # theta-theta: kappa is linear in m_a + m_b (no cross term), tau is linear in theta
        hess[:, 9, 9] = 0.5 * (w2 * kbm[:, 0] - w1 * kbm[:, 2])
        hess[:, 10, 10] = 0.5 * (w2 * kbm[:, 1] - w1 * kbm[:, 3])
        # Gauss-Newton part: sum_i k_i grad(s_i) grad(s_i)^T
        hess += np.einsum("shi,sh,shj->hij", G, stiff, G)
        hess *= self.sign11[:, :, None] * self.sign11[:, None, :]
        # change of variables y_theta = theta + Omega(x): H <- T^T H T + sum_k g_theta_k d2Omega_k
        Ht = hess[:, 9:11, :]                              # (H, 2, 11) rows of the two twist DOFs
        VHt = np.einsum("hki,hkj->hij", V, Ht)            # V^T H[theta, :]
        hess += VHt + np.swapaxes(VHt, 1, 2) + np.einsum("hki,hkl,hlj->hij", V, hess[:, 9:11, 9:11], V)
        hess[:, :9, :9] += self._embed_holonomy_hessian(hh, g_theta)
        return grad, hess

    def _embed_holonomy_gradient(self, hg: np.ndarray) -> np.ndarray:
        """Per hinge, dOmega/dq of its two edges as 11-vectors in the hinge's local DOF order.

        Edge a joins local nodes 0-1 and edge b nodes 1-2; an edge traversed against its direction has its tail
        and head swapped, which for a gradient of the form (-g, g) is a sign flip.
        """
        he, s = self.net.hinge_edges, self.sign
        V = np.zeros((len(he), 2, 11))
        V[:, 0, 0:6] = s[:, 0:1] * hg[he[:, 0]]
        V[:, 1, 3:9] = s[:, 1:2] * hg[he[:, 1]]
        return V

    def _embed_holonomy_hessian(self, hh: np.ndarray, g_theta: np.ndarray) -> np.ndarray:
        """sum_k (dE_h/dtheta_k) d2Omega_k in the hinge's 9x9 position block.

        An edge's block [[B, -B], [-B, B]] is unchanged by swapping its ends, so the sign does not enter.
        """
        he = self.net.hinge_edges
        out = np.zeros((len(he), 9, 9))
        out[:, 0:6, 0:6] = g_theta[:, 0, None, None] * hh[he[:, 0]]
        out[:, 3:9, 3:9] += g_theta[:, 1, None, None] * hh[he[:, 1]]
        return out
