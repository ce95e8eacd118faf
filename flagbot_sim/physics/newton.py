"""The Newton solve of one implicit step, compiled: one call per attempt, Python touching none of its iterations.

Contract (:class:`StepNewton`): given a starting iterate q (the predictor's, prescribed DOFs already set), the
integrator's plan (v = dv q + v0, a = da q + a0, the drive angle) and the committed frames, find q with
``model.residual_norm(r(q)) <= model.force_tol`` (prescribed rows are identity rows), or report failure. What
it keeps between calls is the factorised Jacobian (in the arrow solver's buffers), the integrator coefficient
and the robot's pose it was made at: a later call reuses it, turned with the robot, while it contracts (see
:meth:`~.stepper.Stepper._attempt`, whose algorithm this is, decision for decision). The residual and the
Jacobian are the model's (``RobotModel.residual`` / ``jacobian``) evaluated by the same kernels in the same
order: the frames, each effect the scene lists in its order, the stretching and the bend-twist springs.

"Simulate only the effects a scene calls for": the kernel gets the scene's effects as a list of codes, in the
scene's order, and runs only their terms; an effect without a compiled term (a new one, in Python only) makes
:func:`supported` false and the stepper uses its Python loop.

A steady solver can use the same object once its problem is a plan of the same shape (affine v(q), a(q));
the relative equilibrium's bordered system (physics/steady.py) is not yet one, and keeps its own Newton.

Whole steps (:func:`_advance`, :meth:`StepNewton.advance`, driven by Stepper.advance and Simulation.advance /
run): up to N steps in one call, each the stepper's Python code operation for operation (the integrator's plan,
the predictor, this solve called by address, the Milne error estimate, the error control's step size, the
fixed steps' sampled velocity error) and the observer's per-step work (spin angles, rates, speed, position),
with the drive command an argument. It returns at the steady-state rule's next sample, at the end asked for,
and where only the Python code goes on: a fixed step whose Newton fails at the whole dt (the stepper halves it)
or an error-controlled step below numerics.min_dt (StepFailed). Not for scenes with prescribed DOFs (the
clamp's values are Python) or fixed steps cut for max_turn: those step in Python, with the solve compiled.
"""
from __future__ import annotations

import math

import numpy as np

from .effects import EFFECT_TYPES, GranularYield, Gravity, HeadDrag, HeadTorque, Inertia, RFTDrag
from .frames import angle3
from .jit import address, function_at, kernel, stage
from .linsolve import ArrowSolver

#: the kernels the solve calls, by address (jit.py: no kernel's code is compiled into this one), with the
#: signature the model calls each with: (module, name, signature spec)
KERNELS = (
    ("frames", "_trial_frames", "- f2 i2 f2 f2 i2 f2 f1 f2 f1 f2 f2 f1"),
    ("elastic", "_stretch", "- f2 f1 f1 f1 i2 i2 f1 f1 b"),
    ("elastic", "_bend_twist_local", "- f2 f1 f2 f2 f1 i2 i2 f2 f1 f2 f1 f1 f1 i f f2 f2 f2 f2 b"),
    ("elastic", "_bend_twist_global", "- f2 f2 f1 i2 f2 i2 i2 f2 f2 f1 f1 b"),
    ("effects", "rft", "- f2 f1 f i1 i1 i1 f1 f f i2 f1 f1 i3 i3 i3 b"),
    ("elastic", "tangent_torque", "- f2 f2 f1 i f f i1 f1 f1 i1 i1 b"),
    ("linsolve", "_arrow_factor", "i f1 i1 f1 i1 i1 i1 i1 i1 i1 i1 i1 i1 i1 i1 i i n1 i1 f1 i1 n1 n1"),
    ("linsolve", "_arrow_solve", "- f1 i1 i1 i1 i1 i1 i1 i1 i1 i1 i1 i i n1 i1 f1 i1 n1 i1 i1 f1 f1 f1 f1 n1"),
)
FRAMES, STRETCH, BT_LOCAL, BT_GLOBAL, RFT_FORCE, TANGENT_TORQUE, FACTOR, SOLVE = range(len(KERNELS))
(_trial_frames_at, _stretch_at, _bt_local_at, _bt_global_at, _rft_at, _tangent_torque_at, _factor_at,
 _solve_at) = (function_at(spec) for _, _, spec in KERNELS)


@stage
def _bend_twist(fns, x, theta, t, tc, length, d1, d2, rt, hnodes, hinge_edges, sign, beta, kbar, tbar, kb, kt, hdofs,
                hslots, twist_hinge, angle, S, W, r, J, want_hessian):
    """The bend-twist springs' two kernels in order (ElasticModel._bend_twist's calls), with their work arrays."""
    H = hnodes.shape[0]
    grad = np.empty((H, 11))
    Hs = np.empty((H, 121)) if want_hessian else np.empty((0, 121))
    _bt_local_at(fns[BT_LOCAL])(x, theta, d1, d2, rt, hnodes, hinge_edges, sign, beta, kbar, tbar, kb, kt, twist_hinge,
                                angle, S, W, grad, Hs, want_hessian)
    _bt_global_at(fns[BT_GLOBAL])(t, tc, length, hinge_edges, sign, hdofs, hslots, grad, Hs, r, J, want_hessian)


def kernel_addresses(model) -> np.ndarray:
    """The addresses of :data:`KERNELS` in this process (each compiled or loaded first if it is not yet); 0 for
    the kernel of an effect the model does not have (never called, so never compiled)."""
    import importlib
    kinds = {type(e) for e in model.effects}
    out = []
    for module, name, spec in KERNELS:
        if (name == "rft" and RFTDrag not in kinds) or (name == "tangent_torque" and HeadTorque not in kinds):
            out.append(0)
            continue
        if name == "rft":
            from .effects import rft_kernel
            d = rft_kernel()
        else:
            d = getattr(importlib.import_module(f"{__package__}.{module}"), name)
        out.append(address(d, spec))
    return np.array(out, np.int64)

#: codes of the effects with a compiled force term (motor and clamp act through the springs / prescribed DOFs)
INERTIA, GRAVITY, RFT, HEAD_DRAG, HEAD_TORQUE, GRANULAR, NO_FORCE = 0, 1, 2, 3, 4, 5, 6
_CODES = {Inertia: INERTIA, Gravity: GRAVITY, RFTDrag: RFT, HeadDrag: HEAD_DRAG, HeadTorque: HEAD_TORQUE,
          GranularYield: GRANULAR, EFFECT_TYPES["motor"]: NO_FORCE, EFFECT_TYPES["clamp"]: NO_FORCE}

#: a correction with a kept (not fresh) factorisation is accepted if it shrinks the residual at least this much
CHORD_CONTRACTION = 0.25
#: ... and used further only while the contraction it shows would reach the tolerance in this many more corrections
CHORD_MAX_MORE = 2.0
#: a converged iterate reached with a kept factorisation gets one more correction unless its residual is below
#: this fraction of the tolerance
CHORD_DEEPEN = 0.5
#: a factorisation made for dv/dq = 1/h ... serves steps whose coefficient differs by less than this (relative)
REUSE_DV_CHANGE = 0.15
#: Newton's start continues the motion to first order (not second) once that has landed nearer the converged
#: state, and until the second-order continuation lands this much nearer (in squared, weighted distance) than it
#: (Stepper.predictions has why)
LINEAR_HOLD = 0.05


# ----------------------------------------------------------------------------------------------- evaluation
# Every stage below is called from one place in _newton, with arrays as separate arguments: a tuple of arrays
# handed from function to function compiles to a reference-count update of each member at every hand-over
# (the first version of this module, with the model's arrays in tuples, compiled ~3x longer).
@stage
def _trial(fns, q, N, dv, v0, da, a0, angle, twist_hinge, order, edges, hinge_edges, sign, d1c, tc, ref_prev, t,
           length, d1, d2, rt, v, a, rest, EA, sdofs, sslots, hnodes, beta, kbar, tbar, kb, kt, hdofs, hslots, S, W,
           mass, grav, rk, ra, rb, rl, eta_t, eta_p, rdofs, skk, ska, skb, hd_dofs, hd_w, ht_c, ht_edge, ht_dof,
           ht_x, gy_f, gy_eps2, gy_dofs, fixed, r):
    """The trial configuration q: its frames (t, length, d1, d2, rt), velocity v and acceleration a from the plan,
    and the model's residual r there (each listed effect in the scene's order, then the springs), prescribed rows
    zeroed."""
    x = q[: 3 * N].reshape((N, 3))
    _trial_frames_at(fns[FRAMES])(x, edges, d1c, tc, hinge_edges, sign, ref_prev, t, length, d1, d2, rt)
    n = q.shape[0]
    for i in range(n):
        v[i] = dv * q[i] + v0[i]
        a[i] = da * q[i] + a0[i]
        r[i] = 0.0
    e0 = np.empty(0)
    ne = np.empty(0, np.int64)
    for code in order:
        if code == INERTIA:
            for i in range(n):
                r[i] += mass[i] * a[i]
        elif code == GRAVITY:
            for i in range(grav.shape[0]):
                r[i] -= grav[i]
        elif code == RFT:
            _rft_at(fns[RFT_FORCE])(x, v, dv, rk, ra, rb, rl, eta_t, eta_p, rdofs, r, e0, skk, ska, skb, False)
        elif code == HEAD_DRAG:
            for j in hd_dofs:
                r[j] += hd_w * v[j]
        elif code == HEAD_TORQUE:
            tq = ht_c * v[ht_dof]
            r[ht_dof] += tq
            _tangent_torque_at(fns[TANGENT_TORQUE])(t, tc, length, ht_edge, tq, 0.0, ht_x, r, e0, ne, ne, False)
        elif code == GRANULAR:
            for k in range(gy_dofs.shape[0]):
                j0, j1, j2 = gy_dofs[k, 0], gy_dofs[k, 1], gy_dofs[k, 2]
                c = gy_f / math.sqrt(v[j0] * v[j0] + v[j1] * v[j1] + v[j2] * v[j2] + gy_eps2)
                r[j0] += c * v[j0]
                r[j1] += c * v[j1]
                r[j2] += c * v[j2]
    _stretch_at(fns[STRETCH])(t, length, rest, EA, sdofs, sslots, r, e0, False)
    _bend_twist(fns, x, q[3 * N:], t, tc, length, d1, d2, rt, hnodes, hinge_edges, sign, beta, kbar, tbar, kb, kt,
                hdofs, hslots, twist_hinge, angle, S, W, r, e0, False)
    for f in fixed:
        r[f] = 0.0


@stage
def _jacobian(fns, q, N, dv, da, angle, twist_hinge, order, hinge_edges, sign, tc, t, length, d1, d2, rt, v, rest,
              EA, sdofs, sslots, hnodes, beta, kbar, tbar, kb, kt, hdofs, hslots, S, W, mass, in_slots, rk, ra, rb, rl,
              eta_t, eta_p, rdofs, skk, ska, skb, hd_w, hd_slots, ht_c, ht_edge, ht_dof, ht_x, ht_s0, ht_s1, ht_s2,
              gy_f, gy_eps2, gy_dofs, gy_slots, fix_slots, fix_diag, J):
    """The model's Jacobian (CSC data) at the trial configuration q (frames and v of q), prescribed rows made
    identity rows."""
    x = q[: 3 * N].reshape((N, 3))
    rz = np.zeros(q.shape[0])                    # the terms' residual, discarded
    for s in range(J.shape[0]):
        J[s] = 0.0
    for code in order:
        if code == INERTIA:
            for i in range(in_slots.shape[0]):
                J[in_slots[i]] += mass[i] * da
        elif code == RFT:
            _rft_at(fns[RFT_FORCE])(x, v, dv, rk, ra, rb, rl, eta_t, eta_p, rdofs, rz, J, skk, ska, skb, True)
        elif code == HEAD_DRAG:
            for s in hd_slots:
                J[s] += hd_w * dv
        elif code == HEAD_TORQUE:
            J[ht_s0] += ht_c * dv
            _tangent_torque_at(fns[TANGENT_TORQUE])(t, tc, length, ht_edge, ht_c * v[ht_dof], ht_c * dv, ht_x, rz, J,
                                                    ht_s1, ht_s2, True)
        elif code == GRANULAR:
            for k in range(gy_dofs.shape[0]):
                j0, j1, j2 = gy_dofs[k, 0], gy_dofs[k, 1], gy_dofs[k, 2]
                s = math.sqrt(v[j0] * v[j0] + v[j1] * v[j1] + v[j2] * v[j2] + gy_eps2)
                c = gy_f / s
                s2 = s * s
                for i in range(3):
                    vi = v[gy_dofs[k, i]]
                    for j in range(3):
                        vj = v[gy_dofs[k, j]]
                        J[gy_slots[9 * k + 3 * i + j]] += c * ((1.0 if i == j else 0.0) - vi * vj / s2) * dv
    _stretch_at(fns[STRETCH])(t, length, rest, EA, sdofs, sslots, rz, J, True)
    _bend_twist(fns, x, q[3 * N:], t, tc, length, d1, d2, rt, hnodes, hinge_edges, sign, beta, kbar, tbar, kb, kt,
                hdofs, hslots, twist_hinge, angle, S, W, rz, J, True)
    for s in fix_slots:
        J[s] = 0.0
    for s in fix_diag:
        J[s] = 1.0


@stage
def _norms(r, scale):
    """(largest scaled entry, Euclidean norm of the scaled residual); NaN if any entry is."""
    mx = 0.0
    ss = 0.0
    nan = False
    for i in range(r.shape[0]):
        y = r[i] * scale[i]
        ay = abs(y)
        if ay > mx:
            mx = ay
        elif ay != ay:
            nan = True
        ss += y * y
    return (math.nan if nan else mx), math.sqrt(ss)


@kernel
def residual_norms(r, scale):
    """(largest scaled entry, Euclidean norm of the scaled residual): the stepper's Python loop uses the compiled
    solve's own sums, so that the two take the same decisions."""
    return _norms(r, scale)


@stage
def _sums(w, err, q_new, q_old):
    """(sum w err^2, sum w (q_new - q_old)^2), summed in index order."""
    e2 = 0.0
    d2 = 0.0
    for i in range(w.shape[0]):
        e2 += w[i] * err[i] * err[i]
        d = q_new[i] - q_old[i]
        d2 += w[i] * d * d
    return e2, d2


@kernel
def error_sums(w, err, q_new, q_old):
    """(|err|^2, |q_new - q_old|^2) weighted by w: the error control's sums (Stepper._error_sums), the same in
    the stepper's Python code and the compiled steps (_advance), to the last bit."""
    return _sums(w, err, q_new, q_old)


@kernel
def robot_pose(q, i0, i2, rim, P):
    """The robot's pose into P (9: 3x3 row-major; columns: the axis through the nodes i0 -> i2, the plate rim
    node's direction from it, their cross product): an orthonormal frame that turns with the robot, what relates
    the Jacobians of two configurations of a turning robot (the stepper's Python loop calls it too)."""
    o = 3 * i2
    if i0 != i2:
        a0, a1, a2 = q[o] - q[3 * i0], q[o + 1] - q[3 * i0 + 1], q[o + 2] - q[3 * i0 + 2]
    else:
        a0, a1, a2 = 1.0, 0.0, 0.0
    na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    a0, a1, a2 = a0 / na, a1 / na, a2 / na
    k = 3 * rim
    u0, u1, u2 = q[k] - q[o], q[k + 1] - q[o + 1], q[k + 2] - q[o + 2]
    ua = u0 * a0 + u1 * a1 + u2 * a2
    u0, u1, u2 = u0 - ua * a0, u1 - ua * a1, u2 - ua * a2
    nu = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    u0, u1, u2 = u0 / nu, u1 / nu, u2 / nu
    P[0], P[1], P[2] = a0, u0, a1 * u2 - a2 * u1
    P[3], P[4], P[5] = a1, u1, a2 * u0 - a0 * u2
    P[6], P[7], P[8] = a2, u2, a0 * u1 - a1 * u0


@stage
def _rotated_solve(fns, r, q, N, i0, i2, rim, kept_pose, P, b, x, buf, ab_off, ab_rows, ab_cols, kl, ku, C_off,
                   cc_ptr, cc, cr_ptr, cr, D_off, nc, ipiv, piv_ptr, Y, Y_off, core_piv, chain_dofs, core_dofs, rhs,
                   z, iw):
    """x = R J_then^-1 (R^T r) with the kept factorisation, R the turn from its pose (``kept_pose``, 3x3 row-major)
    to q's (Stepper._rotated_solve)."""
    robot_pose(q, i0, i2, rim, P)
    R = np.empty(9)
    for i in range(3):
        for j in range(3):
            R[3 * i + j] = P[3 * i] * kept_pose[3 * j] + P[3 * i + 1] * kept_pose[3 * j + 1] + \
                P[3 * i + 2] * kept_pose[3 * j + 2]
    for i in range(r.shape[0]):
        b[i] = r[i]
    for m in range(N):
        r0, r1, r2 = r[3 * m], r[3 * m + 1], r[3 * m + 2]
        for j in range(3):
            b[3 * m + j] = r0 * R[j] + r1 * R[3 + j] + r2 * R[6 + j]
    _solve_at(fns[SOLVE])(buf, ab_off, ab_rows, ab_cols, kl, ku, C_off, cc_ptr, cc, cr_ptr, cr, D_off, nc, ipiv,
                          piv_ptr, Y, Y_off, core_piv, chain_dofs, core_dofs, b, x, rhs, z, iw)
    for m in range(N):
        x0, x1, x2 = x[3 * m], x[3 * m + 1], x[3 * m + 2]
        for j in range(3):
            x[3 * m + j] = x0 * R[3 * j] + x1 * R[3 * j + 1] + x2 * R[3 * j + 2]


@stage
def _all_finite(x):
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


#: the signature of _newton as StepNewton.solve calls it (compiled from it by physics.warmup, with no model built)
_EL = "(f1 f1 i2 i2 i2 f1 f2 f1 f1 f1 i2 i2 f2 f2)"
_EF = "(f1 i1 f1 i1 i1 i1 f1 f1 i2 i3 i3 i3 i1 f i1 f i i i1 i i1 i1 f f i2 i1)"
_SOL = "(f1 i1 i1 i1 i1 i1 i1 i1 i1 i1 i1 i1 i i n1 i1 f1 i1 n1 i1 i1 f1 f1 n1)"
NEWTON_SIGNATURE = f"- i1 f1 i f f1 f f1 f i i1 (i2 i2 f2) (f2 f2 f1) {_EL} {_EF} i1 i1 i1 f1 f i {_SOL} i1 i1 f1 f1 f1"
#: the signature of _advance as StepNewton.advance calls it
ADVANCE_SIGNATURE = (f"i i1 i i i i i1 (i2 i2 f2) {_EL} {_EF} i1 i1 i1 f1 {_SOL} i1 i1 f1 f1 f1 i1 f1 "
                     "f2 f3 f3 f3 f2 f1 i1 f1 i1 i1 f1 f2 f1")


def compile_newton() -> None:
    """Compile (or load) the solve and the steps for the signatures they are called with: no kernel they call is
    needed for that (both call them by address)."""
    from .jit import signature
    _newton.compile(signature(NEWTON_SIGNATURE).args)
    _advance.compile(signature(ADVANCE_SIGNATURE).args)


#: what the next evaluation of the trial iterate is for
_START, _DEEPEN, _CHORD, _LINE = 0, 1, 2, 3


@kernel
def _newton(fns, q0, N, dv, v0, da, a0, angle, twist_hinge, order, net, committed, el, ef, fixed, fix_slots,
            fix_diag, scale, tol, max_iterations, sol, dest, axis, kept, kept_pose, stats):
    """One step's Newton solve from the iterate q0 (Stepper._attempt has the algorithm, decision for decision).

    ``kept`` = [a factorisation is kept (1) or not (0), the dv it was made for, (the predictor's order: _advance)],
    ``kept_pose`` (9) its pose: both updated. ``stats``: [0] = the last residual norm, [1:] += line-search cuts,
    Jacobians, chord rejections.
    Returns (converged, iterations, q, v, (t, length, d1, d2, ref_twist)) of the accepted iterate."""
    edges, hinge_edges, sign = net
    d1c, tc, ref_prev = committed
    rest, EA, sdofs, sslots, hnodes, beta, kbar, tbar, kb, kt, hdofs, hslots, S, W = el
    (mass, in_slots, grav, rk, ra, rb, rl, eta, rdofs, skk, ska, skb, hd_dofs, hd_w, hd_slots, ht_c, ht_edge,
     ht_dof, ht_x, ht_s0, ht_s1, ht_s2, gy_f, gy_eps2, gy_dofs, gy_slots) = ef
    (buf, ab_off, ab_rows, ab_cols, kl, ku, B_off, C_off, cc_ptr, cc, cr_ptr, cr, D_off, nc, ipiv, piv_ptr, Y, Y_off,
     core_piv, chain_dofs, core_dofs, rhs, z, iw) = sol
    i0, i2, rim = axis[0], axis[1], axis[2]
    n = q0.shape[0]
    ne, nh = edges.shape[0], hinge_edges.shape[0]
    # the iterate and the trial, each with its frames, velocity, acceleration and residual
    q, t, length, d1, d2, rt = np.empty(n), np.empty((ne, 3)), np.empty(ne), np.empty((ne, 3)), np.empty((ne, 3)), \
        np.empty(nh)
    v, a, r = np.empty(n), np.empty(n), np.empty(n)
    q_t, t_t, length_t, d1_t, d2_t, rt_t = q0, np.empty((ne, 3)), np.empty(ne), np.empty((ne, 3)), \
        np.empty((ne, 3)), np.empty(nh)
    v_t, a_t, r_t = np.empty(n), np.empty(n), np.empty(n)
    dq, dx, b = np.empty(n), np.empty(n), np.empty(n)
    J = np.empty(dest.shape[0])
    P = np.empty(9)
    fresh = False                # the factorisation in hand was made at an iterate of this solve
    chord = kept[0] > 0.0 and abs(dv / kept[1] - 1.0) < REUSE_DV_CHANGE    # or, usable as it is, at an earlier one
    merit_start = -1.0
    watchdog = 3
    it = 0
    rn = merit0 = alpha = 0.0
    want = _START
    done = 0                         # 1: converged, -1: failed
    while done == 0:
        _trial(fns, q_t, N, dv, v0, da, a0, angle, twist_hinge, order, edges, hinge_edges, sign, d1c, tc, ref_prev,
               t_t, length_t, d1_t, d2_t, rt_t, v_t, a_t, rest, EA, sdofs, sslots, hnodes, beta, kbar, tbar, kb, kt,
               hdofs, hslots, S, W, mass, grav, rk, ra, rb, rl, eta[0], eta[1], rdofs, skk, ska, skb, hd_dofs, hd_w,
               ht_c, ht_edge, ht_dof, ht_x, gy_f, gy_eps2, gy_dofs, fixed, r_t)
        m_max, m = _norms(r_t, scale)
        take = False                 # the trial becomes the iterate
        newton = False               # a Newton correction (fresh Jacobian, line search) comes next
        if want == _START:
            take = True
        elif want == _DEEPEN:        # the extra correction of a converged iterate: kept only if it is better
            it += 1
            done = 1
            if not m_max < rn:
                break
            take = True
        elif want == _CHORD:
            if _all_finite(dq) and math.isfinite(m) and (m <= CHORD_CONTRACTION * merit0 or m_max <= tol):
                take = True
                rho = m / merit0
                chord = m_max <= tol or (rho > 0.0 and math.log(tol / m_max) / math.log(rho) <= CHORD_MAX_MORE)
            else:
                chord = False        # too slow a contraction: a fresh Jacobian here, and Newton steps
                stats[3] += 1.0
                fresh = False
                newton = True
        else:                        # _LINE
            if math.isfinite(m) and m < (1.0 - 1e-4 * alpha) * merit0:
                take = True
            elif alpha == 1.0 and watchdog > 0 and math.isfinite(m) and m < merit_start:
                watchdog -= 1        # the watchdog (Stepper._attempt)
                take = True
            else:
                alpha *= 0.5
                stats[1] += 1.0
                if alpha < 1.0 / 64.0:
                    done = -1
                    break
                for i in range(n):
                    q_t[i] = q[i] + alpha * dq[i]
                continue
            if take:
                chord = alpha == 1.0
                fresh = True
        next_ = -1
        if take:
            if want == _CHORD or want == _LINE:
                it += 1
            q, q_t = q_t, q
            t, t_t = t_t, t
            length, length_t = length_t, length
            d1, d1_t = d1_t, d1
            d2, d2_t = d2_t, d2
            rt, rt_t = rt_t, rt
            v, v_t = v_t, v
            a, a_t = a_t, a
            r, r_t = r_t, r
            if done != 0:
                break
            rn, merit0 = m_max, m
            stats[0] = rn
            if not math.isfinite(rn):
                done = -1
                break
            if rn <= tol:
                if not (chord and rn > CHORD_DEEPEN * tol):
                    done = 1
                    break
                next_ = _DEEPEN      # one more correction with the kept factorisation (Stepper._attempt)
            elif it == max_iterations:
                done = -1
                break
            elif chord:
                next_ = _CHORD
            else:
                newton = True
        if newton:
            if not fresh:
                _jacobian(fns, q, N, dv, da, angle, twist_hinge, order, hinge_edges, sign, tc, t, length, d1, d2, rt,
                          v, rest, EA, sdofs, sslots, hnodes, beta, kbar, tbar, kb, kt, hdofs, hslots, S, W, mass,
                          in_slots, rk, ra, rb, rl, eta[0], eta[1], rdofs, skk, ska, skb, hd_w, hd_slots, ht_c,
                          ht_edge, ht_dof, ht_x, ht_s0, ht_s1, ht_s2, gy_f, gy_eps2, gy_dofs, gy_slots, fix_slots,
                          fix_diag, J)
                stats[2] += 1.0
                kept[0] = 0.0
                if _factor_at(fns[FACTOR])(J, dest, buf, ab_off, ab_rows, ab_cols, kl, ku, B_off, C_off, cc_ptr, cc,
                                           cr_ptr, cr, D_off, nc, ipiv, piv_ptr, Y, Y_off, core_piv, iw) != 0:
                    done = -1
                    break
                kept[0] = 1.0
                kept[1] = dv
                robot_pose(q, i0, i2, rim, kept_pose)
                fresh = True
            next_ = _LINE
        _rotated_solve(fns, r, q, N, i0, i2, rim, kept_pose, P, b, dx, buf, ab_off, ab_rows, ab_cols, kl, ku, C_off,
                       cc_ptr, cc, cr_ptr, cr, D_off, nc, ipiv, piv_ptr, Y, Y_off, core_piv, chain_dofs, core_dofs,
                       rhs, z, iw)
        for i in range(n):
            dq[i] = -dx[i]
            q_t[i] = q[i] + dq[i]
        if next_ == _LINE:
            if not _all_finite(dq):
                done = -1
                break
            if merit_start < 0.0:
                merit_start = merit0
            alpha = 1.0
        want = next_
    return done > 0, it, q, v, (t, length, d1, d2, rt)


# ----------------------------------------------------------------------------------------------- steps
#: the solve as _advance calls it, by address (its code is not compiled again into _advance): its return type,
#: then NEWTON_SIGNATURE's arguments; and the predictor's kernel (stepper._predict_cylindrical)
NEWTON_AT = "(b i f1 f1 (f2 f1 f2 f2 f1)) " + NEWTON_SIGNATURE[2:]
PREDICT_AT = "- f2 f2 f2 f f f f f b i i i f2 f2"
_newton_at, _predict_at = function_at(NEWTON_AT), function_at(PREDICT_AT)

#: _advance's layout of its arrays (Stepper.advance fills and reads them)
#: Q rows: the state's q, v, q_prev, v_prev, q_prev2; the state before it's v_prev and q_prev2
Q_ROWS = 7
#: sc: the state's t, drive angle, h, h_prev, h_next; the state before it's the same five
#: flags: the state has q_prev, q_prev2; the state before it has q_prev2; there is a state before it
#: cfg: dt (fixed steps) or the largest step, tol, rtol, atol, min_dt, turn limit, t_end, t_stop, due_at, omega,
#:      the velocity error's gain (VELOCITY_GAIN of the integrator)
#: icfg: integrator order, max_iterations, error control (1/0), max steps, fixed steps so far (in/out), a driver
#:       (1/0), the error norm's count, VELOCITY_ERROR_EVERY, steps committed (out)
#: obs_i: has a head, head edge, shaft edge, the observed node, the axis's nodes (2)
#: ob: phi_h, phi_t, rate_h, rate_t, speed, axis (3), position (3)
#: out rows (one per step): t, velocity error, Newton iterations, phi_h, phi_t, position (3), dt reductions,
#:      dt_min
OUT_COLS = 10
#: last: the last step's Newton iterations, residual, line-search cuts, Jacobians, chord rejections, dt
#:       reductions, rejections, error norm, dt_min, the last step size tried, velocity error, its step size,
#:       the predictor's order (kept[2]) the step began with (Simulation.advance restores it where the step is
#:       taken again in Python)
LAST = 13
#: what _advance returns: the steps asked for are done (or an output time is reached); a fixed step's Newton
#: failed (the stepper's Python code halves it: Stepper.step(resume=...)); an error-controlled step fell below
#: numerics.min_dt (StepFailed)
ADVANCED, FIXED_FAILED, BELOW_MIN_DT = 0, 1, 2


@kernel
def _advance(fns, nfn, pfn, N, twist_hinge, codes, net, el, ef, fixed, fix_slots, fix_diag, scale, sol, dest, axis,
             kept, kept_pose, stats, pax, w_norm, Q, T, D1, D2, RT, sc, flags, cfg, icfg, obs_i, ob, out, last):
    """Up to icfg[3] steps (Stepper.step with one sub-step / Stepper.step_adaptive, then Observer.record and
    Simulation.step's counters), each the same arithmetic as the Python code, in one call: the prediction, the
    plan of the integrator, the solve (_newton, by address ``nfn``), the error estimate and the next step size,
    the observer's spin angles, rates and position. The arrays (layout above) hold the state and the one
    before it, in and out. Returns ADVANCED, FIXED_FAILED or BELOW_MIN_DT; icfg[8] = the steps committed."""
    n = Q.shape[1]
    order, max_it, adaptive, max_steps = icfg[0], icfg[1], icfg[2] != 0, icfg[3]
    has_driver, count, every = icfg[5] != 0, icfg[6], icfg[7]
    dt, tol, rtol, atol, min_dt, turn, t_end, t_stop, due_at, omega, vgain = (
        cfg[0], cfg[1], cfg[2], cfg[3], cfg[4], cfg[5], cfg[6], cfg[7], cfg[8], cfg[9], cfg[10])
    i0, i1, i2 = pax[0], pax[1], pax[2]
    has_head, e_head, e_shaft, node, ka, kb = obs_i[0], obs_i[1], obs_i[2], obs_i[3], obs_i[4], obs_i[5]
    v0, a0, qt, ql, err = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    m = T.shape[1] * 3
    Tf, D1f, D2f = T.reshape(2 * m), D1.reshape(2 * m), D2.reshape(2 * m)
    k = 0
    status = ADVANCED
    icfg[8] = 0
    while k < max_steps:
        q, v, qp, vp, qp2 = Q[0], Q[1], Q[2], Q[3], Q[4]
        t0, ang0, h1, h2, h_next = sc[0], sc[1], sc[2], sc[3], sc[4]
        have1, have2 = flags[0] != 0, flags[1] != 0
        if not t0 < t_stop:
            break
        if adaptive:
            h = min(h_next if h_next != 0.0 else dt, dt, turn)
            h_end = t_end - t0
            if h >= h_end:
                h = h_end
            elif h > 0.5 * h_end:
                h = 0.5 * h_end
        else:
            h = dt
        its_all = 0
        last[12] = kept[2]
        reductions = rejections = 0
        cuts = jacs = chords = 0.0
        norm = 0.0
        ve = math.nan
        while True:
            # -- one attempt (Stepper._attempt): the plan, the prediction, the solve
            angle = ang0 + (omega * h if has_driver else 0.0)
            if order == 2 and have1 and h1 > 0.0:
                w = h / h1
                c0 = (1.0 + 2.0 * w) / (1.0 + w)
                c1 = -(1.0 + w)
                c2 = w * w / (1.0 + w)
                dv = c0 / h
                for i in range(n):
                    v0[i] = (c1 * q[i] + c2 * qp[i]) / h
                    g = (c1 * v[i] + c2 * vp[i]) / h
                    a0[i] = dv * v0[i] + g
                da = dv * dv
            else:
                ih = 1.0 / h
                for i in range(n):
                    v0[i] = -ih * q[i]
                    a0[i] = ih * (v0[i] - v[i])
                dv = ih
                da = ih * ih
            both = False                 # both continuations made (stepper.continuations)
            if h1 <= 0.0 or not have1:
                for i in range(n):
                    qt[i] = q[i] + h * v[i]
            else:
                both = h2 > 0.0 and have2
                _continued(pfn, N, q, qp, qp2, h, h1, h2, both, i0, i1, i2, qt, ql)
            for j in range(4):
                stats[j] = 0.0
            ok, its, qn, vn, fr = _newton_at(nfn)(
                fns, (ql if both and kept[2] > 0.0 else qt).copy(), N, dv, v0, da, a0, angle, twist_hinge, codes,
                net, (D1[0], T[0], RT[0]), el, ef, fixed, fix_slots, fix_diag, scale, tol, max_it, sol, dest, axis,
                kept, kept_pose, stats)
            if ok and both:
                for i in range(n):
                    err[i] = qn[i] - ql[i]
                e_lin, e_quad = _sums(w_norm, err, qn, qt)
                _choose_order(kept, e_quad, e_lin)
            cuts += stats[1]
            jacs += stats[2]
            chords += stats[3]
            if not adaptive:
                if not ok:
                    status = FIXED_FAILED
                break
            # -- error control (Stepper.step_adaptive)
            if not ok:
                factor = 0.25
                reductions += 1
            else:
                its_all += its
                # the integrator's Milne estimate (ImplicitEuler.error / BDF2.error), if it has the history
                have_err = _milne(order, have1, have2, h, h1, h2, q, qp, qp2, qn, err)
                gain = 3.0 if order == 2 else 2.0
                if order == 2 and have1 and h1 > 0.0:
                    w = h / h1
                    gain *= (1.0 + 2.0 * w) / (1.0 + w)
                norm = 0.0
                e2 = d2 = 0.0
                if have_err:
                    e2, d2 = _sums(w_norm, err, qn, q)
                    if count != 0:
                        norm = gain * math.sqrt(e2) / (atol * math.sqrt(count) + rtol * math.sqrt(d2))
                if norm <= 1.0:
                    if have_err:
                        ve = _velocity_error(order, vgain, h, h1, e2, d2)
                    grow = 2.0 if norm == 0.0 else min(2.0, max(1.0, 0.9 * norm ** (-1.0 / (order + 1))))
                    h_next = min(grow * h, dt)
                    break
                factor = max(0.2, 0.9 * norm ** (-1.0 / (order + 1)))
                rejections += 1
            h *= factor
            if h < min_dt:
                status = BELOW_MIN_DT
                h = h / factor                # the step size of the last attempt (Stepper._failed)
                break
        last[0] = its_all if adaptive or not ok else its
        last[1], last[2], last[3], last[4] = stats[0], cuts, jacs, chords
        last[5], last[6], last[7], last[8], last[9] = reductions, rejections, norm, h, h
        if status != ADVANCED:
            break
        if not adaptive:
            its_all = its
            h_next = 0.0
            icfg[4] += 1            # Stepper._sample_velocity_error
            if icfg[4] % every == 0:
                have_err = _milne(order, have1, have2, h, h1, h2, q, qp, qp2, qn, err)
                if have_err:
                    e2, d2 = _sums(w_norm, err, qn, q)
                    ve = _velocity_error(order, vgain, h, h1, e2, d2)
        last[10] = ve
        t1 = t0 + h
        tn, ln, d1n, d2n, rtn = fr
        # -- the observer (Observer.record), from the committed state (old) to the new one
        dts = t1 - t0
        if has_head:
            b0, b1, b2 = qn[3 * kb] - qn[3 * ka], qn[3 * kb + 1] - qn[3 * ka + 1], qn[3 * kb + 2] - qn[3 * ka + 2]
            nb = math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
            b0, b1, b2 = b0 / nb, b1 / nb, b2 / nb
            dh = -_spin(qn, q, N, e_head, D1f, d1n, b0, b1, b2)
            dtt = _spin(qn, q, N, e_shaft, D1f, d1n, b0, b1, b2)
        else:
            b0, b1, b2 = 1.0, 0.0, 0.0
            dh = dtt = 0.0
        ob[0] += dh
        ob[1] += dtt
        ob[2] = dh / dts
        ob[3] = dtt / dts
        y0, y1, y2 = qn[3 * node], qn[3 * node + 1], qn[3 * node + 2]
        dd0, dd1, dd2 = y0 - ob[8], y1 - ob[9], y2 - ob[10]
        ob[4] = -(dd0 * b0 + dd1 * b1 + dd2 * b2) / dts
        ob[5], ob[6], ob[7], ob[8], ob[9], ob[10] = b0, b1, b2, y0, y1, y2
        # -- commit: the state before becomes the one before the new state
        # (element by element, in 1-D: numba's array-to-slice copy compiles ~5 s, a 2-D index twice a 1-D one)
        vp2, qp3 = Q[5], Q[6]
        for i in range(n):
            vp2[i] = vp[i]
            qp3[i] = qp2[i]
            qp2[i] = qp[i]
            vp[i] = v[i]
            qp[i] = q[i]
            q[i] = qn[i]
            v[i] = vn[i]
        _shift(Tf, tn.reshape(m))
        _shift(D1f, d1n.reshape(m))
        _shift(D2f, d2n.reshape(m))
        _shift(RT.reshape(RT.size), rtn)
        for j in range(5):
            sc[5 + j] = sc[j]
        sc[0], sc[1], sc[2], sc[3], sc[4] = t1, angle, h, h1, h_next
        flags[2] = flags[1]
        flags[1] = flags[0]
        flags[0] = 1
        flags[3] = 1
        o = out[k]
        o[0], o[1], o[2], o[3], o[4] = t1, ve, its_all, ob[0], ob[1]
        o[5], o[6], o[7], o[8], o[9] = y0, y1, y2, reductions, h
        k += 1
        icfg[8] = k
        if t1 >= due_at:
            break
    return status


@stage
def _continued(pfn, N, q, qp, qp2, h, h1, h2, second, i0, i1, i2, out, out1):
    """stepper.continuations: the motion of the states q, qp, qp2 (steps h1, h2 before) continued by h to second
    order into ``out`` (to first order if not ``second``), and if ``second`` to first order into ``out1``."""
    p1 = h + (h * (h + h1) / (h1 + h2) if second else 0.0)
    p0 = -h * (h + h1) / (h1 + h2) if second else 0.0
    for i in range(q.shape[0]):
        s1 = (q[i] - qp[i]) / h1
        s0 = (qp[i] - qp2[i]) / h2 if second else s1
        out[i] = q[i] + p1 * s1 + p0 * s0
        if second:
            out1[i] = q[i] + h * s1
    x = q[: 3 * N].reshape((N, 3))
    x1 = qp[: 3 * N].reshape((N, 3))
    x2 = qp2[: 3 * N].reshape((N, 3)) if second else x1
    _predict_at(pfn)(x, x1, x2, h, h1, h2 if second else 0.0, p1, p0, second, i0, i1, i2,
                     out[: 3 * N].reshape((N, 3)), (out1 if second else out)[: 3 * N].reshape((N, 3)))


@stage
def _choose_order(kept, e_quad, e_lin):
    """The order of the next continuation (kept[2]: 1 first, 0 second; Stepper._choose_order) from how far the
    converged state lies from the two continuations of this step (weighted squares)."""
    if kept[2] > 0.0:
        if e_quad < LINEAR_HOLD * e_lin:
            kept[2] = 0.0
    elif e_lin < e_quad:
        kept[2] = 1.0


@stage
def _milne(order, have1, have2, h, h1, h2, q, qp, qp2, qn, err):
    """The integrator's local error estimate of the step h to qn into err (ImplicitEuler.error / BDF2.error,
    the same expressions), if the state (q, qp, qp2; steps h1, h2) has the history it needs: whether it has."""
    n = q.shape[0]
    if order == 2:
        if not (have2 and h1 > 0.0 and h2 > 0.0):
            return False
        T0, T1, x = -(h1 + h2), -h1, h
        L0 = (x - T1) * x / ((T0 - T1) * T0)
        L1 = (x - T0) * x / ((T1 - T0) * T1)
        L2 = (x - T0) * (x - T1) / (T0 * T1)
        c0 = (1.0 + 2.0 * h / h1) / (1.0 + h / h1)
        f = (h / c0) / (h / c0 + h + h1 + h2)
        for i in range(n):
            err[i] = (qn[i] - (L0 * qp2[i] + L1 * qp[i] + L2 * q[i])) * f
        return True
    if not (have1 and h1 > 0.0):
        return False
    r1 = h / h1
    f = h / (2.0 * h + h1)
    for i in range(n):
        err[i] = (qn[i] - (q[i] + r1 * (q[i] - qp[i]))) * f
    return True


@stage
def _shift(buf, new):
    """buf = [current, before]: the current values become those before, ``new`` the current ones."""
    m = new.shape[0]
    for i in range(m):
        buf[m + i] = buf[i]
        buf[i] = new[i]


@stage
def _spin(qn, q, N, e, D1f, d1n, b0, b1, b2):
    """Observer._spin_increment of edge e: its twist angle's change plus its reference director's turn about
    the axis b."""
    k = 3 * N + e
    return qn[k] - q[k] + angle3(D1f[3 * e], D1f[3 * e + 1], D1f[3 * e + 2], d1n[e, 0], d1n[e, 1], d1n[e, 2],
                                 b0, b1, b2)


@stage
def _velocity_error(order, vgain, h, h1, e2, d2):
    """Stepper.velocity_error from the error sums."""
    if d2 <= 0.0:
        return 0.0
    gain = vgain
    if order == 2 and h1 > 0.0:
        w = h / h1
        gain *= (1.0 + 2.0 * w) / (1.0 + w)
    return gain * math.sqrt(e2 / d2)


# ----------------------------------------------------------------------------------------------- the object
def supported(model, solver) -> bool:
    """Whether the compiled solve covers this model: the arrow solver, and only effects with a compiled term."""
    return isinstance(solver, ArrowSolver) and all(type(e) in _CODES for e in model.effects)


def _i64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.int64)


class StepNewton:
    """The Newton solve of a step (module docstring: the contract). ``kept`` / ``kept_pose`` are the kept
    factorisation's coefficient and pose, shared with the stepper's Python loop (the same solver buffers);
    ``predictor`` the predictor's kernel (stepper._predict_cylindrical), which the whole steps call by address."""

    def __init__(self, model, solver: ArrowSolver, axis_nodes: tuple[int, int, int], rim: int,
                 kept: np.ndarray, kept_pose: np.ndarray, predictor):
        net, el = model.net, model.elastic
        self.model = model
        self.N = int(net.n_nodes)
        self.ndof = int(net.ndof)
        self.twist_hinge = int(model.twist_hinge)
        self.order = np.array([_CODES[type(e)] for e in model.effects], np.int64)
        self.net = (_i64(net.edges), _i64(net.hinge_edges), np.ascontiguousarray(el.sign))
        self.el = (net.edge_rest_length, net.EA, el.stretch_dofs, el.stretch_slots, net.hinge_nodes, el.beta,
                   el.kappa_bar, el.tau_bar, el.k_bend, el.k_twist, el.hinge_dofs, el.hinge_slots, el._strains,
                   el._moments)
        self.ef = self._effect_terms(model)
        self.fixed = _i64(model.prescribed_dofs)
        slots, diag = model.pattern.fix_rows_mask(model.prescribed_dofs)
        self.fix_slots, self.fix_diag = _i64(slots), _i64(diag)
        self.scale = model.scale
        k = solver._k
        self.sol = (solver._buf, k["ab_off"], k["ab_rows"], k["ab_cols"], k["kl"], k["ku"], solver._B_off,
                    k["C_off"], k["cc_ptr"], k["cc"], k["cr_ptr"], k["cr"], np.int64(k["D_off"]), np.int64(k["nc"]),
                    solver._ipiv, solver._piv_ptr, solver._Y, solver._Y_off, solver._core_piv, solver._chain_dofs,
                    solver._core, solver._rhs, solver._z, solver._iw)
        self.dest = solver.dest
        i0, _, i2 = axis_nodes
        self.axis = np.array([i0, i2, rim], np.int64)
        self.kept, self.kept_pose = kept, kept_pose
        self.stats = np.zeros(4)
        self.fns = kernel_addresses(model)
        #: the solve's and the predictor's machine code, which _advance calls by address
        self.newton_address = address(_newton, NEWTON_AT)
        self.predict_address = address(predictor, PREDICT_AT)

    @staticmethod
    def _effect_terms(model) -> tuple:
        """Each compiled term's arrays (empty where the scene does not list the effect)."""
        f0, i0 = np.zeros(0), np.zeros(0, np.int64)
        e = {type(x): x for x in model.effects}
        inertia, grav, rft = e.get(Inertia), e.get(Gravity), e.get(RFTDrag)
        hd, ht, gy = e.get(HeadDrag), e.get(HeadTorque), e.get(GranularYield)
        s33 = np.zeros((0, 3, 3), np.int64)
        return (
            inertia.mass if inertia else f0, _i64(inertia.slots[0]) if inertia else i0,
            grav.f if grav else f0,
            *((rft.k, rft.a, rft.b, rft.l, np.array([rft.eta_t, rft.eta_p]), _i64(rft.dof_k),
               *(np.ascontiguousarray(s) for s in rft._s)) if rft else
              (i0, i0, i0, f0, np.zeros(2), np.zeros((0, 3), np.int64), s33, s33, s33)),
            _i64(hd.dofs) if hd else i0, float(hd.w) if hd else 0.0, _i64(hd.slots[0]) if hd else i0,
            float(ht.c) if ht else 0.0, int(ht.edge) if ht else 0, int(ht.dof) if ht else 0,
            _i64(ht.x_dofs) if ht else i0, int(ht.slots[0][0]) if ht else 0, _i64(ht.slots[1]) if ht else i0,
            _i64(ht.slots[2]) if ht else i0,
            float(gy.f) if gy else 0.0, float(gy.eps2) if gy else 0.0,
            _i64(gy.dofs) if gy else np.zeros((0, 3), np.int64), _i64(gy.slots[0]) if gy else i0)

    def solve(self, q: np.ndarray, committed, plan, tol: float, max_iterations: int):
        """Newton from iterate ``q`` (overwritten) for the step ``plan`` from the ``committed`` frames, to the
        residual norm ``tol`` (N) within ``max_iterations`` corrections: (converged,
        iterations, q, v, frames (t, length, d1, d2, ref_twist)); the line-search cuts, Jacobians and chord
        rejections are added to ``self.stats[1:]``, stats[0] is the last residual norm. Raises
        ZeroDivisionError where a formula divides by an exact zero (a folded configuration)."""
        return _newton(self.fns, q, self.N, float(plan.dv_dq), plan.v0, float(plan.da_dq), plan.a0,
                       float(plan.drive_angle), self.twist_hinge, self.order, self.net, (committed.d1, committed.t, committed.ref_twist),
                       self.el, self.ef, self.fixed, self.fix_slots, self.fix_diag, self.scale, float(tol),
                       int(max_iterations), self.sol, self.dest, self.axis, self.kept, self.kept_pose, self.stats)

    def advance(self, b, max_steps: int) -> int:
        """Up to ``max_steps`` steps from the state in the buffers ``b`` (stepper.StepBuffers, its cfg set by
        Stepper.advance) in one compiled call (_advance): its status; b.icfg[8] the steps taken."""
        b.icfg[3] = max_steps
        return _advance(self.fns, self.newton_address, self.predict_address, self.N, self.twist_hinge, self.order,
                        self.net, self.el, self.ef, self.fixed, self.fix_slots, self.fix_diag, self.scale, self.sol,
                        self.dest, self.axis, self.kept, self.kept_pose, self.stats, b.pax, b.w_norm, b.Q, b.T,
                        b.D1, b.D2, b.RT, b.sc, b.flags, b.cfg, b.icfg, b.obs_i, b.ob, b.out, b.last)
