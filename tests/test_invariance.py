"""Rigid-body motions of the undeformed robot cost no elastic energy, and are its only zero-energy modes."""
import math

import numpy as np
import pytest

from flagbot_sim.physics.frames import parallel_transport, signed_angle, unit_rows
from flagbot_sim.physics.model import RobotModel
from flagbot_sim.scene import load_scene

from fd import dense_elastic_hessian


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def rigidly_moved(model, R, shift):
    """DOFs of the undeformed robot rotated by R and shifted, with every material frame turned by R too."""
    net, el = model.net, model.elastic
    x = net.nodes @ R.T + shift
    q = net.initial_q()
    q[: 3 * net.n_nodes] = x.ravel()
    t, _ = unit_rows(x[net.edges[:, 1]] - x[net.edges[:, 0]])
    d1 = parallel_transport(el.frames0.d1, el.frames0.t, t)      # what time-parallel transport gives
    q[3 * net.n_nodes:] = signed_angle(d1, el.frames0.d1 @ R.T, t)   # material frame = R * rest frame
    return q


@pytest.mark.parametrize("n", [1, 2, 3, 5])
@pytest.mark.parametrize("axis,angle", [((1, 0, 0), 0.4), ((1, 0, 0), 2.9), ((0, 1, 0), 0.7), ((1, 2, -1), 1.3)])
def test_rigid_motion_changes_no_elastic_energy(n, axis, angle):
    model = RobotModel(load_scene("design1", [f"robot.n_flagella={n}", "flagellum.length=0.03"]))
    el = model.elastic
    q = rigidly_moved(model, rotation(axis, angle), np.array([0.3, -0.1, 0.05]))
    fr = el.trial_frames(q, el.frames0)
    scale = el.k_bend.max() * 1e-2 ** 2           # energy of a 1e-2 bend at the stiffest hinge
    assert el.energy(q, fr) < 1e-20 * scale / 1e-4 + 1e-24
    k1, k2, tau = el.hinge_strains(q, fr)
    assert np.abs(np.stack([k1, k2], 1) - el.kappa_bar).max() < 1e-12
    assert np.abs(tau - el.tau_bar).max() < 1e-12


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_only_rigid_body_modes_have_zero_stiffness(n):
    """Exactly six zero eigenvalues: no floppy joint, plate or motor hinge (a 90-degree hinge averaging opposite
    frames once left the plate free to turn about the shaft)."""
    model = RobotModel(load_scene("design1", [f"robot.n_flagella={n}", "flagellum.length=0.02"]))
    el, st = model.elastic, model.initial_state()
    H = dense_elastic_hessian(el, st.q, el.trial_frames(st.q, st.frames))
    w = np.linalg.eigvalsh(H)
    zero = np.abs(w) < 1e-12 * w[-1]        # round-off level of the rigid parts
    assert zero.sum() == 6
    assert w[6] > 1e-4      # the softest deformation mode (a flagellum bending/twisting) is clearly stiff
