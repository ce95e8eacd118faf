"""Beam-theory estimator of the paper's section "Beam theory based analysis of propulsion".

LB (closed form), NLB w/o head and NLB (Chebyshev collocation for the balance, solve_bvp otherwise) flagellum
solutions and the robot's force/torque balance for omega_h, omega_t and v_h at a motor speed omega_T. numpy/scipy
only; SI units. See docs/beam.md.

    from flagbot_sim.beam import BeamParams, solve_balance
    res = solve_balance(BeamParams.from_scene(scene), scene.omega_T, regime="nlb")
"""
from .balance import (REGIMES, BalanceError, BalanceResult, balance_residual, flagellum_state, lb_head_speed,
                      solve_balance, solve_balance_curve)
from .linear import (FlagellumSolution, lb_deflection, lb_F_p, lb_F_x, lb_load, lb_tip_deflection, solve_lb)
from .nonlinear import BeamSolveError, NLBSolveError, solve_nlb, solve_nlb_coupled
from .params import BeamParams

__all__ = ["REGIMES", "BalanceError", "BalanceResult", "BeamParams", "BeamSolveError", "FlagellumSolution",
           "NLBSolveError", "balance_residual", "flagellum_state", "lb_F_p", "lb_F_x", "lb_deflection",
           "lb_head_speed", "lb_load", "lb_tip_deflection", "solve_balance", "solve_balance_curve", "solve_lb",
           "solve_nlb", "solve_nlb_coupled"]
