"""The medium's coefficients: resistive-force theory on the flagella and the drag and torque on the head.

Two media (scene key ``medium.model``; sources and discussion in docs/physics.md, "Media"):

* ``granular_rft`` (the default, the paper's): the slender-body forms with an effective coefficient ``medium.mu``
  fitted to the experiments, eta_t = 2 pi mu / (ln(2L/r0) - 1/2), eta_p = 4 pi mu / (ln(2L/r0) + 1/2) (paper Eq.
  RFT coefficients), and the modified Stokes laws C1 6 pi mu R_h, C2 8 pi mu R_h^3 on the head with the fitted
  factors C1, C2.
* ``viscous``: a Newtonian fluid of dynamic viscosity ``medium.mu`` (Pa s). Straight flagella: Gray & Hancock's
  (1955) coefficients, eta_t = 2 pi mu / (ln(2 lambda/r0) - 1/2), eta_n = 4 pi mu / (ln(2 lambda/r0) + 1/2), with
  the flagellum's length L as the length scale lambda (the same forms as the paper's). Helical flagella:
  Lighthill's (1976) coefficients, eta_t = 2 pi mu / ln(2q/r0), eta_n = 4 pi mu / (ln(2q/r0) + 1/2), q = 0.09
  Lambda, Lambda the flagellum's arc length per turn. The head: exact Stokes drag 6 pi mu R_h v and torque
  8 pi mu R_h^3 omega on a sphere (C1, C2 are the granular model's fitted factors and do not enter).

Against the flagellum's bending stiffness EI they set the elasto-viscous time eta_p L^4 / EI, the unit of the
paper's normalised speeds (:func:`relaxation_time`, :func:`normalise_omega`, :func:`normalise_speed`). The effects
(:mod:`.effects`), the beam theory and the reference rod take their coefficients from here; a scene only declares
and validates the values they are made of.

Every function takes a scene (duck-typed: its ``medium``, ``flagellum``, ``head`` and ``plate`` sections). Plain
Python (no numba): the scene validator imports it.
"""
from __future__ import annotations

import math

from .network import section

#: the media a scene can choose (``medium.model``), with one line each for ``flagbot scenes`` and the docs
MODELS: dict[str, str] = {
    "granular_rft": "the paper's granular RFT: effective mu, eta from the straight-rod forms, head law C1, C2",
    "viscous": "Newtonian fluid of viscosity mu: Gray-Hancock (straight) / Lighthill (helix) RFT, exact Stokes "
               "head",
}
#: Lighthill's q = LIGHTHILL_Q x the arc length of one turn of the helix
LIGHTHILL_Q = 0.09


def helix_turn_length(radius: float, pitch: float) -> float:
    """Arc length (m) of one turn of a helix of ``radius`` advancing |``pitch``| per turn."""
    return math.hypot(pitch, 2.0 * math.pi * radius)


def _length_scale(scene) -> tuple[float, str]:
    """(l, formula): the length whose ratio to the flagellum radius sets the coefficients' logarithm, ln(2 l/r0),
    and the name of the formula they come from. The helix's radius is the attachment radius plate.diameter / 2."""
    fl = scene.flagellum
    if scene.medium.model == "viscous" and fl.helix_pitch != 0.0:
        return LIGHTHILL_Q * helix_turn_length(0.5 * scene.plate.diameter, fl.helix_pitch), "lighthill_1976"
    if scene.medium.model == "viscous":
        return fl.length, "gray_hancock_1955"
    return fl.length, "paper_granular_rft"


def rft_formula(scene) -> str:
    """Which formula gives the scene's RFT coefficients: 'paper_granular_rft', 'gray_hancock_1955' or
    'lighthill_1976'."""
    return _length_scale(scene)[1]


def rft_coefficients(scene) -> tuple[float, float]:
    """(eta_t, eta_p) in N s/m^2: the drag per unit length and unit velocity along and across the flagellum's
    tangent, for the scene's medium (``medium.model``, ``medium.mu``), flagellum (length, radius) and helix."""
    l, formula = _length_scale(scene)
    mu = scene.medium.mu
    log = math.log(2.0 * l / scene.flagellum.radius)
    if formula == "lighthill_1976":
        return 2.0 * math.pi * mu / log, 4.0 * math.pi * mu / (log + 0.5)
    return 2.0 * math.pi * mu / (log - 0.5), 4.0 * math.pi * mu / (log + 0.5)


def _head_factors(scene) -> tuple[float, float]:
    """(C1, C2): the scene's fitted factors in the granular medium, the exact Stokes sphere's 1, 1 in the fluid."""
    return (1.0, 1.0) if scene.medium.model == "viscous" else (scene.head.C1, scene.head.C2)


def head_drag_coefficient(scene) -> float:
    """N s/m: the head's drag per speed, C1 6 pi mu R_h (granular_rft) or 6 pi mu R_h (viscous)."""
    return _head_factors(scene)[0] * 6.0 * math.pi * scene.medium.mu * scene.head.radius


def head_torque_coefficient(scene) -> float:
    """N m s: the head's torque per spin rate, C2 8 pi mu R_h^3 (granular_rft) or 8 pi mu R_h^3 (viscous)."""
    return _head_factors(scene)[1] * 8.0 * math.pi * scene.medium.mu * scene.head.radius ** 3


def bending_stiffness(scene) -> float:
    """EI = pi/4 E r0^4 (N m^2) of the flagellum, the stiffness the medium's load is measured against."""
    return scene.flagellum.youngs_modulus * section(scene.flagellum)[1]


def force_scale(scene) -> float:
    """EI / L^2 (N): the flagellum's bending force, the unit of numerics.force_tol."""
    return bending_stiffness(scene) / scene.flagellum.length ** 2


def relaxation_time(scene) -> float:
    """Elasto-viscous time eta_p L^4 / EI (s): omega_bar = omega * this."""
    return rft_coefficients(scene)[1] * scene.flagellum.length ** 4 / bending_stiffness(scene)


def normalise_omega(scene, omega: float) -> float:
    """omega_bar = omega eta_p L^4 / EI (dimensionless)."""
    return omega * relaxation_time(scene)


def normalise_speed(scene, v: float) -> float:
    """v_bar = v eta_p L^3 / EI (dimensionless)."""
    return v * rft_coefficients(scene)[1] * scene.flagellum.length ** 3 / bending_stiffness(scene)


def spin_drag_coefficient(scene) -> float:
    """c (N s: torque per length per rad/s) of the 'spin_drag' effect, by ``medium.spin_drag``: 'viscous',
    4 pi mu r0^2 (Stokes flow round a cylinder turning about its axis); 'granular', spin_traction x eta_t r0^2 (an
    assumption: the grains resist the surface sliding round the axis as they resist it sliding along it);
    'medium' (the default), whichever of the two ``medium.model`` is (docs/physics.md, "Axial spin drag")."""
    med, r0 = scene.medium, scene.flagellum.radius
    kind = med.spin_drag
    if kind == "medium":
        kind = "viscous" if med.model == "viscous" else "granular"
    if kind == "viscous":
        return 4.0 * math.pi * med.mu * r0 * r0
    return med.spin_traction * rft_coefficients(scene)[0] * r0 * r0


def slenderness_problem(scene) -> str | None:
    """Why resistive-force theory cannot be applied to this flagellum (its coefficients would be negative or
    infinite), or None: it needs ln(2 l / r0) > 1/2 with l the formula's length scale."""
    l, formula = _length_scale(scene)
    r0 = scene.flagellum.radius
    if 2.0 * l / r0 > math.exp(0.5):
        return None
    what = (f"{LIGHTHILL_Q} x the arc length of one turn, {l:.3g} m (Lighthill's q)" if formula == "lighthill_1976"
            else f"the flagellum length {l:.3g} m")
    return f"needs log(2 l / r0) > 1/2 with l = {what}; got 2 l / r0 = {2 * l / r0:.3g}"


def coefficients_report(scene) -> dict:
    """The ``rft_coefficients`` entry of every run and steady JSON: the medium, the formula and its eta_t, eta_n
    (N s/m^2) for this scene."""
    eta_t, eta_n = rft_coefficients(scene)
    return {"model": scene.medium.model, "formula": rft_formula(scene), "eta_t": eta_t, "eta_n": eta_n}


def describe(report: dict) -> str:
    """One line for the human-readable summaries: the medium and its RFT coefficients."""
    return (f"medium {report['model']} ({report['formula']}): eta_t = {report['eta_t']:.4g}, "
            f"eta_n = {report['eta_n']:.4g} N s/m^2")
