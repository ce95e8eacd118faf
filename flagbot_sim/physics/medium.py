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

Plain Python (no numba): the scene validator imports it.
"""
from __future__ import annotations

import math

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


def rft_length_scale(model: str, length: float, helix_radius: float, pitch: float) -> tuple[float, str]:
    """(l, formula): the length whose ratio to the flagellum radius sets the coefficients' logarithm, ln(2 l/r0),
    and the name of the formula they come from."""
    if model == "viscous" and pitch != 0.0:
        return LIGHTHILL_Q * helix_turn_length(helix_radius, pitch), "lighthill_1976"
    if model == "viscous":
        return length, "gray_hancock_1955"
    return length, "paper_granular_rft"


def rft_coefficients(model: str, mu: float, length: float, radius: float, helix_radius: float = 0.0,
                     pitch: float = 0.0) -> tuple[float, float]:
    """(eta_t, eta_n) in N s/m^2: the drag per unit length and unit velocity along and across the flagellum's
    tangent, for ``model`` (MODELS), coefficient or viscosity ``mu`` (Pa s), flagellum ``length`` and ``radius``
    (m), and its helix (radius and pitch, m; pitch 0 = straight)."""
    l, formula = rft_length_scale(model, length, helix_radius, pitch)
    log = math.log(2.0 * l / radius)
    if formula == "lighthill_1976":
        return 2.0 * math.pi * mu / log, 4.0 * math.pi * mu / (log + 0.5)
    return 2.0 * math.pi * mu / (log - 0.5), 4.0 * math.pi * mu / (log + 0.5)


def head_coefficients(model: str, mu: float, head_radius: float, C1: float, C2: float) -> tuple[float, float]:
    """(drag N s/m, torque N m s) on the spherical head: C1 6 pi mu R_h and C2 8 pi mu R_h^3 for the granular
    model, the exact Stokes sphere (C1 = C2 = 1) for the viscous one."""
    if model == "viscous":
        C1 = C2 = 1.0
    return C1 * 6.0 * math.pi * mu * head_radius, C2 * 8.0 * math.pi * mu * head_radius ** 3


def slenderness_problem(model: str, length: float, radius: float, helix_radius: float, pitch: float
                        ) -> str | None:
    """Why resistive-force theory cannot be applied to this flagellum (its coefficients would be negative or
    infinite), or None: it needs ln(2 l / r0) > 1/2 with l the formula's length scale."""
    l, formula = rft_length_scale(model, length, helix_radius, pitch)
    if 2.0 * l / radius > math.exp(0.5):
        return None
    what = (f"{LIGHTHILL_Q} x the arc length of one turn, {l:.3g} m (Lighthill's q)" if formula == "lighthill_1976"
            else f"the flagellum length {l:.3g} m")
    return f"needs log(2 l / r0) > 1/2 with l = {what}; got 2 l / r0 = {2 * l / radius:.3g}"


def coefficients_report(scene) -> dict:
    """The ``rft_coefficients`` entry of every run and steady JSON: the medium, the formula and its eta_t, eta_n
    (N s/m^2) for this scene."""
    eta_t, eta_n = scene.rft_coefficients
    return {"model": scene.medium.model, "formula": scene.rft_formula, "eta_t": eta_t, "eta_n": eta_n}


def describe(report: dict) -> str:
    """One line for the human-readable summaries: the medium and its RFT coefficients."""
    return (f"medium {report['model']} ({report['formula']}): eta_t = {report['eta_t']:.4g}, "
            f"eta_n = {report['eta_n']:.4g} N s/m^2")
