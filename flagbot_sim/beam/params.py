"""The parameters the beam-theory estimator needs, and the dimensionless groups it solves in.

The beam estimator sees a robot only through eight numbers (paper section "Beam theory based analysis of
propulsion"): the number of flagella ``n``, the flagellum length ``L`` and bending stiffness ``EI``, the RFT drag
coefficients ``eta_t`` and ``eta_p``, the plate radius ``R_d`` and the two head coefficients of Eqs.
stokes_drag_refined / stokes_torque_refined. Taking them from the same :class:`~flagbot_sim.scene.Scene` as the
DER simulator keeps the two frameworks on identical parameters.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..physics import medium
from ..scene import Scene, SceneError


@dataclass(frozen=True)
class BeamParams:
    """SI parameters of one robot for beam theory (forces are per flagellum, like the paper's)."""

    n: int            # number of flagella
    L: float          # flagellum length (m)
    EI: float         # bending stiffness (N m^2)
    eta_t: float      # tangential RFT drag per length (N s / m^2)
    eta_p: float      # perpendicular RFT drag per length (N s / m^2)
    R_d: float        # plate radius L_p / 2: the flagella's distance from the axis (m)
    c_drag: float     # C1 * 6 pi mu R_h, head drag per head speed (N s / m)
    c_torque: float   # C2 * 8 pi mu R_h^3, head torque per head spin (N m s)

    def __post_init__(self):
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < 1:
            raise ValueError(f"BeamParams.n must be a positive integer, got {self.n!r}")
        for name in ("L", "EI", "eta_t", "eta_p", "R_d", "c_drag", "c_torque"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"BeamParams.{name} must be a positive finite number, got {value!r}")

    @classmethod
    def for_free_robot(cls, scene: Scene) -> "BeamParams":
        """:meth:`from_scene`, refusing a scene whose flagellum is clamped: the balance solves the free robot's
        head torque and drag for omega_h, omega_t and v_h, so it would print free-robot numbers (or zeros) for a
        robot whose head is held (flagbot beam and beam_node)."""
        if scene.clamped:
            raise SceneError(f"beam: scene {scene.scene.name!r} clamps its flagellum ('clamp' in scene.effects: the head "
                             "is held fixed), but the beam balance solves the free robot's head torque and drag "
                             "balance for omega_h, omega_t and v_h; use a free-robot scene (design1, design2), or "
                             "`flagbot run` for the clamped flagellum")
        return cls.from_scene(scene)

    @classmethod
    def from_scene(cls, scene: Scene) -> "BeamParams":
        # The balance equations divide by the head coefficients: a scene without head drag or torque (C1 or
        # C2 = 0, allowed for the DER) has no beam-theory steady state, so say which key to change.
        if scene.flagellum.helix_pitch != 0.0:
            raise SceneError(f"flagellum.helix_pitch = {scene.flagellum.helix_pitch:g} m: the beam estimator models "
                             "naturally straight flagella (the paper's beam theory); use the DER (flagbot run, "
                             "flagbot steady) for helical ones")
        for key, value in (("head.C1", scene.head.C1), ("head.C2", scene.head.C2)):
            if value <= 0 and scene.medium.model == "granular_rft":   # (the viscous head is the exact sphere)
                raise SceneError(f"{key} = {value!r}: the beam estimator needs a head drag and torque "
                                 f"(Eqs. vHead, OHead divide by them); set {key} > 0")
        eta_t, eta_p = medium.rft_coefficients(scene)
        return cls(n=scene.robot.n_flagella, L=scene.flagellum.length, EI=medium.bending_stiffness(scene),
                   eta_t=eta_t, eta_p=eta_p, R_d=scene.R_d, c_drag=medium.head_drag_coefficient(scene),
                   c_torque=medium.head_torque_coefficient(scene))

    # ---- dimensionless groups (paper section "Parameter fitting") ----
    @property
    def kappa(self) -> float:
        """eta_t / eta_p; the nonlinear load terms carry (kappa - 1) < 0 for slender flagella."""
        return self.eta_t / self.eta_p

    @property
    def relaxation_time(self) -> float:
        """Elasto-viscous time eta_p L^4 / EI (s); omega_bar = omega * this."""
        return self.eta_p * self.L ** 4 / self.EI

    def normalise_omega(self, omega: float) -> float:
        """omega_bar = omega eta_p L^4 / EI, used for omega_T, omega_h and omega_t alike (see docs/beam.md)."""
        return omega * self.relaxation_time

    def normalise_speed(self, v: float) -> float:
        """v_bar = v eta_p L^3 / EI."""
        return v * self.eta_p * self.L ** 3 / self.EI

    def load_number(self, omega_t: float) -> float:
        """A = eta_p omega_t R_d L^3 / EI = omega_t_bar R_d / L: the LB load p_t in units of EI / L^3.

        The LB tip deflection is w(L)/L = A/8, so A also measures how far from linear the flagellum is.
        """
        return self.eta_p * omega_t * self.R_d * self.L ** 3 / self.EI

    def omega_from_load_number(self, A: float) -> float:
        return A * self.EI / (self.eta_p * self.R_d * self.L ** 3)

    def speed_from_number(self, B: float) -> float:
        """Inverse of :meth:`normalise_speed`."""
        return B * self.EI / (self.eta_p * self.L ** 3)

    @property
    def head_drag_number(self) -> float:
        """c_drag / (eta_p L): head drag relative to the drag on one flagellum's length."""
        return self.c_drag / (self.eta_p * self.L)

    @property
    def linear_torque_ratio(self) -> float:
        """n eta_p R_d^2 L / c_torque: omega_h / omega_t in LB (Eqs. linearFx, OHead)."""
        return self.n * self.eta_p * self.R_d ** 2 * self.L / self.c_torque
