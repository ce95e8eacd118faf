"""Independent references for validating the simulator (numpy/scipy only).

    from flagbot_sim.reference import from_scene, solve_clamped_rod
    ref = from_scene(load_scene("clamped_flagellum"))      # steady Fx, Tx, tip of the rotating clamped rod
"""
from .rod_bvp import DEFAULT_TOL, RodBVPError, RodSolution, from_scene, solve_clamped_rod

__all__ = ["DEFAULT_TOL", "RodBVPError", "RodSolution", "from_scene", "solve_clamped_rod"]
