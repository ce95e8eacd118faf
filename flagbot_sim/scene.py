"""Scene files: load, validate and override the parameters of one simulation.

A scene is a TOML file (stdlib ``tomllib``) with one table per section. Every key is declared once here, with
its unit, type and allowed range; anything else is an error that names the key and lists the valid ones. Values
are SI inside the program; the only non-SI key is ``motor.omega_rpm`` (the paper quotes motor speeds in rpm),
converted once by :attr:`Scene.omega_T`.

Scenes choose the physical effects they want in ``scene.effects``; the model builds only those
(see :mod:`flagbot_sim.physics.model`). This module is the schema, its reading and its validation only: what the
values mean physically (the medium's coefficients, EI, the normalised speeds) is computed by the physics
(:mod:`flagbot_sim.physics.medium`); the generic field checks are :mod:`flagbot_sim.fields`, finding and safely
reading a file :mod:`flagbot_sim.scene_files`.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .fields import SceneError, check_value, control_character, names as _names, short, spec
from .physics import medium as _medium
from .physics.effects import EFFECT_TYPES
from .physics.medium import MODELS as MEDIUM_MODELS, force_scale
from .physics.network import NEWTON_ROUNDOFFS, build_network, flagellum_edge_count
from .scene_files import read_scene_text, resolve_scene_path
from .units import RPM

#: Effects a scene may list, with what each one adds to the model: the physics' one registry (an effect is one
#: class in physics.effects, plus its constants' keys in a section here)
EFFECTS: dict[str, str] = {name: cls.description for name, cls in EFFECT_TYPES.items()}
#: effects that need the head (the clamped scene holds it fixed)
HEAD_EFFECTS = tuple(name for name, cls in EFFECT_TYPES.items() if cls.on_head)


#: every length (m) lies in [MIN_LENGTH, MAX_LENGTH]: 1 um to 1 km, and the smallest part of the robot is at least
#: MIN_LENGTH_RATIO of its overall size (below that an edge vanishes in the rounding of the node positions, and
#: the reference frames divide by a zero length)
MIN_LENGTH, MAX_LENGTH, MIN_LENGTH_RATIO = 1.0e-6, 1.0e3, 1.0e-5

def _f(default, unit="", doc="", **bounds):
    return field(default=default, metadata=spec(unit, doc=doc, **bounds))


#: Accuracy presets: discretisation values applied on top of the scene file, under explicit overrides. Their
#: measured error and wall time are in docs/accuracy.md (`flagbot bench accuracy --parts presets`): over 0.5-100
#: rpm (clamped flagellum of both designs, vs the rod BVP) and on the free robot (vs the converged steady
#: solution), 'fast' (BDF2, error-controlled, 8.22 mm edges) <= 2%, 'default' (nothing added: the scene file
#: and the TimeSection defaults, BDF2 at the scene's dt = 1e-2 s, 4.11 mm edges) <= 1%, 'accurate' (BDF2,
#: rtol 1e-3, 2.06 mm edges) <= 0.2%; 'paper' is the paper's own numerics (implicit Euler, dt = 1e-2 s,
#: 4.11 mm edges: up to 2.4%). The error-controlled presets take at most 0.1 s per step, so that a live run
#: (sim_node) still advances smoothly.
PRESETS: dict[str, dict[str, Any]] = {
    "fast": {"time.integrator": "bdf2", "time.rtol": 1.0e-2, "time.dt": 0.1, "flagellum.edge_length": 8.22e-3},
    "default": {},
    "accurate": {"time.integrator": "bdf2", "time.rtol": 1.0e-3, "time.dt": 0.1,
                 "flagellum.edge_length": 2.055e-3},
    "paper": {"time.integrator": "implicit_euler", "time.rtol": 0.0, "time.dt": 1.0e-2,
              "flagellum.edge_length": 4.11e-3},
}


@dataclass(frozen=True)
class SceneSection:
    name: str = _f("unnamed", doc="scene name", max_len=200, one_line=True)
    description: str = _f("", doc="free text", max_len=10000)
    effects: tuple = _f(("inertia", "rft", "head_drag", "head_torque", "motor"),
                        doc="physical effects to build, from: " + ", ".join(EFFECTS), items="str", max_len=64)
    preset: str = _f("default", doc="accuracy preset: discretisation applied on top of the scene file "
                                    "(overrides still win); see PRESETS", choices=tuple(PRESETS))


@dataclass(frozen=True)
class RobotSection:
    n_flagella: int = _f(2, doc="number of flagella n", ge=1, le=12)


@dataclass(frozen=True)
class MotorSection:
    omega_rpm: float = _f(100.0, "rpm", "motor speed omega_T (clamped scene: the clamp's rotation speed)",
                          ge=-1.0e4, le=1.0e4)


@dataclass(frozen=True)
class TimeSection:
    dt: float = _f(1.0e-2, "s", "time step (with time.rtol > 0: the first and the largest step)", ge=1.0e-6,
                   le=10.0)
    duration: float = _f(20.0, "s", "simulated time of a CLI run", gt=0.0, le=1.0e7)
    integrator: str = _f("bdf2", "", "time integrator: 'bdf2' (second order, L-stable) or 'implicit_euler' "
                                     "(first order, the paper's; scene.preset = 'paper' sets it)",
                         choices=("implicit_euler", "bdf2"))
    rtol: float = _f(0.0, "", "error control: tolerated relative error of the velocities a step takes, calibrated "
                              "so that the steady outputs stay within it (0 = fixed steps of time.dt)",
                     ge=0.0, lt=1.0)
    atol: float = _f(1.0e-9, "m", "error control: absolute floor of the step's error (twist angles count times the "
                                  "edge length)", gt=0.0, le=1.0)
    max_turn: float = _f(0.5, "rad", "largest angle the motor (or clamp) turns in one step: smaller steps are "
                                     "taken at high speed, so no speed aliases (at most a quarter turn: the "
                                     "clamp's plate arm must not reverse within a step)", gt=0.0, le=0.5 * math.pi)


@dataclass(frozen=True)
class FlagellumSection:
    length: float = _f(0.111, "m", "flagellum length L", ge=MIN_LENGTH, le=MAX_LENGTH)
    radius: float = _f(3.2e-3, "m", "flagellum radius r0", ge=MIN_LENGTH, le=MAX_LENGTH)
    edge_length: float = _f(4.11e-3, "m", "target length of a flagellum edge (rounded to fit L)", ge=MIN_LENGTH,
                            le=MAX_LENGTH)
    youngs_modulus: float = _f(1.2e6, "Pa", "Young's modulus E", gt=0.0, le=1.0e13)
    poisson_ratio: float = _f(0.5, "", "Poisson's ratio (G = E / (2(1+nu)))", ge=-0.99, le=0.5)
    density: float = _f(1000.0, "kg/m^3", "density of flagella, plate and head", gt=0.0, le=1.0e5)
    helix_pitch: float = _f(0.0, "m", "natural shape: 0 = straight; otherwise a helix coaxial with the robot "
                                      "through the flagellum's attachment point (radius plate.diameter/2), "
                                      "advancing |P| per turn, P > 0 right-handed, P < 0 left-handed",
                            ge=-MAX_LENGTH, le=MAX_LENGTH)


@dataclass(frozen=True)
class MediumSection:
    model: str = _f("granular_rft", "", "the medium: 'granular_rft' (the paper's: mu an effective coefficient, head "
                                        "law with C1, C2) or 'viscous' (a Newtonian fluid of viscosity mu: "
                                        "Gray-Hancock / Lighthill RFT, exact Stokes head)",
                    choices=tuple(MEDIUM_MODELS))
    mu: float = _f(6.828, "Pa*s", "medium coefficient mu (RFT and Stokes terms): granular_rft's fitted effective "
                                  "value, or the viscous fluid's dynamic viscosity", gt=0.0, le=1.0e10)
    # the 'granular_yield' effect's constants (docs/physics.md, "Granular yield"): the default puts design 1's
    # threshold (n = 2) at the paper's omega_T^s ~ 50 rpm
    yield_force: float = _f(5.35e-4, "N", "granular yield: force the head must overcome to move (used only with "
                                         "the 'granular_yield' effect)", ge=0.0, le=1.0e6)
    yield_speed: float = _f(1.0e-7, "m/s", "granular yield: regularisation speed v_eps of the Coulomb law (the "
                                           "creep speed scale below the threshold)", gt=0.0, le=1.0e3)
    # the 'spin_drag' effect's coefficient (docs/physics.md, "Axial spin drag"): not in the paper's model
    spin_drag: str = _f("medium", "", "spin drag on the flagella about their own axes (used only with the "
                                      "'spin_drag' effect): 'viscous', 4*pi*mu*r0^2 per length (Stokes flow "
                                      "round a rotating cylinder), 'granular', spin_traction*eta_t*r0^2 (the "
                                      "grains shear the surface as in axial sliding: an assumption), or 'medium': "
                                      "the one of medium.model", choices=("medium", "viscous", "granular"))
    spin_traction: float = _f(1.0, "", "granular spin drag (medium.spin_drag = 'granular'): surface traction per "
                                       "sliding speed when spinning, relative to axial sliding's "
                                       "eta_t / (2*pi*r0)", ge=0.0, le=1.0e6)


@dataclass(frozen=True)
class HeadSection:
    radius: float = _f(0.02, "m", "head radius R_h", ge=MIN_LENGTH, le=MAX_LENGTH)
    C1: float = _f(2.420, "", "Stokes drag factor C1 (granular_rft; the viscous head is the exact sphere)",
                   ge=0.0, le=1.0e6)
    C2: float = _f(0.039, "", "Stokes torque factor C2 (granular_rft; the viscous head is the exact sphere)",
                   ge=0.0, le=1.0e6)


@dataclass(frozen=True)
class PlateSection:
    diameter: float = _f(0.04, "m", "plate diameter L_p; flagella sit at R_d = L_p/2", ge=MIN_LENGTH,
                         le=MAX_LENGTH)
    thickness: float = _f(4.11e-3, "m", "plate thickness: the rigid axial stub each flagellum is clamped in",
                          ge=MIN_LENGTH, le=MAX_LENGTH)


#: smallest accuracy.rtol accepted (0 is off): below it the steady-state rule's and Newton's floors (~1e-5) and the
#: rod reference's own tolerance come close
MIN_ACCURACY_RTOL = 1.0e-4
#: the discretisation that accuracy.rtol chooses: an explicit override of any of them is refused beside it
ACCURACY_CHOOSES = ("time.rtol", "time.integrator", "time.dt", "flagellum.edge_length")


#: fewest Newton iterations per attempt accepted. On the built-in scenes and presets (2 s from rest, with a command
#: reversal) a step takes 2-3 iterations from its predictor (the median), up to ~10 after a reversal. Measured dt
#: reductions (design 1, 0.2 s = 20 steps): cap 1: 2150 (107 s of wall time on a loaded host), 2: 83, 3: 19; over
#: 150 steps a cap of 3 took 55 and failed a step of the 'accurate' preset, 4 took 7, 5 took 4, 25 none
MIN_NEWTON_ITERATIONS = 4


@dataclass(frozen=True)
class NumericsSection:
    rigid_factor: float = _f(1.0e3, "", "stiffness of head/plate relative to the flagellum", ge=1.0, le=1.0e8)
    force_tol: float = _f(1.0e-7, "", "Newton tolerance on the force residual, relative to EI/L^2 (never below "
                                      "the robot's round-off floor; a value under both the default and that floor "
                                      "is refused)", gt=0.0, lt=1.0)
    max_iterations: int = _f(25, "", "Newton iterations per attempt", ge=MIN_NEWTON_ITERATIONS, le=500,
                             why="a step's Newton solve takes 2-3 from its predictor, up to ~10 after a command "
                                 f"reversal: with fewer than {MIN_NEWTON_ITERATIONS} most steps are cut into "
                                 "sub-steps and the run crawls (1: 2150 dt reductions in 0.2 s of design 1)")
    min_dt: float = _f(1.0e-6, "s", "smallest time step before a step is declared failed", ge=1.0e-12)
    linear_solver: str = _f("auto", "", "Newton's linear solver: 'arrow' (banded flagella + Schur complement of "
                                        "the core), 'splu' (SuperLU), 'auto' (arrow when the network allows)",
                            choices=("auto", "arrow", "splu"))


@dataclass(frozen=True)
class ObserveSection:
    steady_window: float = _f(2.0, "s", "window over which steady-state rates are averaged", gt=0.0, le=1.0e6)
    steady_rtol: float = _f(1.0e-3, "", "relative change between windows counted as steady (with time.rtol > 0: "
                                        "at most time.rtol / 10)", gt=0.0, le=1.0)


@dataclass(frozen=True)
class GravitySection:
    g: tuple = _f((0.0, 0.0, -9.81), "m/s^2", "gravity vector (used only with the 'gravity' effect)", items="number",
                  length=3, ge=-1.0e4, le=1.0e4)


@dataclass(frozen=True)
class AccuracySection:
    rtol: float = _f(0.0, "", "total relative numerical error requested of every output (time + space): chooses "
                              "time.rtol, time.integrator = 'bdf2', time.dt = 0.1 s and flagellum.edge_length "
                              "(physics/error_estimate.resolve_accuracy; 0 = off, the scene's own values)",
                     ge=0.0, le=0.1)


SECTIONS: dict[str, type] = {
    "scene": SceneSection, "robot": RobotSection, "motor": MotorSection, "time": TimeSection,
    "flagellum": FlagellumSection, "medium": MediumSection, "head": HeadSection, "plate": PlateSection,
    "numerics": NumericsSection, "observe": ObserveSection, "gravity": GravitySection,
    "accuracy": AccuracySection,
}

@dataclass(frozen=True)
class Scene:
    scene: SceneSection = SceneSection()
    robot: RobotSection = RobotSection()
    motor: MotorSection = MotorSection()
    time: TimeSection = TimeSection()
    flagellum: FlagellumSection = FlagellumSection()
    medium: MediumSection = MediumSection()
    head: HeadSection = HeadSection()
    plate: PlateSection = PlateSection()
    numerics: NumericsSection = NumericsSection()
    observe: ObserveSection = ObserveSection()
    accuracy: AccuracySection = AccuracySection()
    gravity: GravitySection = GravitySection()
    source: str = ""
    file_data: dict = field(default_factory=dict, compare=False, repr=False)
    overrides: dict = field(default_factory=dict, compare=False, repr=False)

    # ---- derived quantities, SI ----
    @property
    def omega_T(self) -> float:
        """Motor speed in rad/s."""
        return self.motor.omega_rpm * RPM

    @property
    def effects(self) -> tuple[str, ...]:
        return tuple(self.scene.effects)

    @property
    def clamped(self) -> bool:
        return "clamp" in self.scene.effects

    @property
    def R_d(self) -> float:
        return 0.5 * self.plate.diameter

    # ---- conversion ----
    def to_dict(self) -> dict[str, dict[str, Any]]:
        out = {}
        for name in SECTIONS:
            sec = getattr(self, name)
            out[name] = {f.name: (list(v) if isinstance(v := getattr(sec, f.name), tuple) else v)
                         for f in dataclasses.fields(sec)}
        return out

    def flat(self) -> dict[str, Any]:
        return {f"{s}.{k}": v for s, d in self.to_dict().items() for k, v in d.items()}

    def with_overrides(self, overrides: dict[str, Any] | list[str]) -> "Scene":
        """A new scene with ``section.key`` values replaced (values or ``key=value`` strings)."""
        if isinstance(overrides, (list, tuple)):
            overrides = parse_overrides(overrides)
        for dotted in overrides:
            _split_key(dotted)
        return scene_from_dict(self.file_data, source=self.source, overrides={**self.overrides, **overrides})

    def to_toml(self) -> str:
        lines = []
        for section, values in self.to_dict().items():
            lines.append(f"[{section}]")
            for k, v in values.items():
                lines.append(f"{k} = {_toml_value(v)}")
            lines.append("")
        return "\n".join(lines)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def _split_key(dotted: Any) -> tuple[str, str]:
    if not isinstance(dotted, str) or "." not in dotted:
        raise SceneError(f"override key {short(dotted)} must be 'section.key'; sections: {', '.join(SECTIONS)}")
    section, key = dotted.split(".", 1)
    if section not in SECTIONS:
        raise SceneError(f"unknown section {short(section)} in {short(dotted)}; valid sections: "
                         f"{', '.join(SECTIONS)}")
    valid = [f.name for f in dataclasses.fields(SECTIONS[section])]
    if key not in valid:
        raise SceneError(f"unknown key {short(dotted)}; valid keys in [{section}]: {', '.join(valid)}")
    return section, key


def _toml_loads(text: str, what: str) -> dict:
    """``tomllib.loads`` with every failure as a SceneError (deep nesting exhausts tomllib's recursion)."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{what}: not valid TOML: {exc}") from None
    except RecursionError:
        raise SceneError(f"{what}: {_deepest(text)} nested too deeply for a scene") from None


def _deepest(text: str, limit: int = 100) -> str:
    """Where a TOML text nests brackets more than ``limit`` deep, as 'section.key (line N)', for the message
    after tomllib ran out of recursion (a rough scan: brackets inside strings count too)."""
    section, depth = "", 0
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if depth == 0 and stripped.startswith("[") and stripped.endswith("]"):
            section = stripped.strip("[]").strip()
            continue
        if depth == 0:
            key = line.split("=", 1)[0].strip() if "=" in line else ""
        for c in line:
            depth += (c in "[{") - (c in "]}")
            if depth > limit:
                dotted = f"{section}.{key}" if section and key else (key or section or "a value")
                return f"{short(dotted, 80)} (line {number}): the value is"
    return "a value is"


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """Parse ``["flagellum.length=0.2", "scene.effects=['rft']"]`` with TOML value syntax.

    A bare word that is not valid TOML (``scene.name=foo``) is taken as a string.
    """
    out: dict[str, Any] = {}
    for item in items:
        if not isinstance(item, str) or "=" not in item:
            raise SceneError(f"override {short(item)} must look like section.key=value")
        bad = control_character(item)
        if bad:
            # a newline would make a second TOML line of the value, silently dropped: one override is one line
            key, raw = item.split("=", 1)
            raise SceneError(f"override {short(key.strip(), 60)} = {short(raw.strip())} holds {bad}: each "
                             "override (--set, a scene_overrides entry) is one section.key=value on one line")
        key, raw = item.split("=", 1)
        key = key.strip()
        _split_key(key)
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        except RecursionError:
            raise SceneError(f"{key}: the value is nested too deeply") from None
        out[key] = value
    return out


def scene_from_dict(data: dict[str, Any], source: str = "", overrides: dict[str, Any] | None = None) -> Scene:
    """Validate a nested dict (as read from TOML) into a :class:`Scene`.

    Precedence, lowest first: the defaults declared here, the file's values, the accuracy preset
    (``scene.preset``), then ``overrides`` (``{"section.key": value}``).
    """
    overrides = dict(overrides or {})
    if not isinstance(data, dict):
        raise SceneError(f"a scene must be a table of sections, got {short(data)}")
    unknown = [s for s in data if s not in SECTIONS]
    if unknown:
        raise SceneError(f"unknown section(s) {_names(unknown)}; valid sections: {', '.join(SECTIONS)}")
    merged: dict[str, dict[str, Any]] = {s: {} for s in SECTIONS}
    for s, values in data.items():
        if not isinstance(values, dict):
            raise SceneError(f"[{s}] must be a table of key = value, got {s} = {short(values)}")
        merged[s].update(values)
    for dotted in overrides:
        _split_key(dotted)
    preset_name = overrides.get("scene.preset", merged["scene"].get("preset", "default"))
    if not isinstance(preset_name, str) or preset_name not in PRESETS:
        raise SceneError(f"scene.preset = {short(preset_name)} is not allowed; choose one of {', '.join(PRESETS)}")
    for dotted, value in list(PRESETS[preset_name].items()) + list(overrides.items()):
        s, k = _split_key(dotted)
        merged[s][k] = value
    sections = {}
    for s, cls in SECTIONS.items():
        fields = {f.name: f for f in dataclasses.fields(cls)}
        values = merged[s]
        bad = [k for k in values if k not in fields]
        if bad:
            raise SceneError(f"unknown key(s) {_names(f'{s}.{k}' for k in bad)}; valid keys in [{s}]: "
                             f"{', '.join(fields)}")
        kwargs = {k: check_value(f"{s}.{k}", fields[k], v) for k, v in values.items()}
        sections[s] = cls(**kwargs)
    scene = Scene(**sections, source=source, file_data=data, overrides=overrides)
    _check_consistency(scene)
    return scene


def _check_consistency(sc: Scene) -> None:
    eff = sc.scene.effects
    for e in eff:
        if e not in EFFECTS:
            raise SceneError(f"scene.effects: unknown effect {short(e)}; valid effects: {', '.join(EFFECTS)}")
    if len(set(eff)) != len(eff):
        raise SceneError(f"scene.effects lists an effect twice: {short(list(eff))}")
    fl = sc.flagellum
    if fl.radius >= fl.length:
        raise SceneError(f"flagellum.radius = {fl.radius} m must be smaller than flagellum.length = {fl.length} m")
    if 2.0 * fl.length / fl.radius <= math.exp(0.5):
        raise SceneError("flagellum.length / flagellum.radius is too small for resistive-force theory "
                         f"(needs log(2L/r0) > 1/2, got 2L/r0 = {2 * fl.length / fl.radius:.3g})")
    slender = _medium.slenderness_problem(sc)
    if slender:
        raise SceneError(f"flagellum.radius = {fl.radius:g} m is too thick for Lighthill's resistive-force theory of "
                         f"this helix (flagellum.helix_pitch = {fl.helix_pitch:g} m): it {slender}")
    if sc.medium.model == "viscous" and "granular_yield" in eff:
        raise SceneError("scene.effects: 'granular_yield' is the granular medium's yield; medium.model = 'viscous' "
                         "has none (remove the effect, or use medium.model = 'granular_rft')")
    if fl.edge_length > fl.length:
        raise SceneError(f"flagellum.edge_length = {fl.edge_length} m must not exceed flagellum.length = "
                         f"{fl.length} m")
    if fl.length / fl.edge_length > 20000:
        raise SceneError(f"flagellum.length = {fl.length} m over flagellum.edge_length = {fl.edge_length} m gives "
                         f"{fl.length / fl.edge_length:.3g} edges per flagellum, more than 20000")
    _check_proportions(sc)
    _check_helix(sc)
    if sc.numerics.min_dt >= sc.time.dt:
        raise SceneError(f"numerics.min_dt = {sc.numerics.min_dt} s must be smaller than time.dt = {sc.time.dt} s")
    _check_force_tol(sc)
    acc = sc.accuracy.rtol
    if 0.0 < acc < MIN_ACCURACY_RTOL:
        raise SceneError(f"accuracy.rtol = {acc:g} is below what the steady-state rule and Newton's tolerance can "
                         f"resolve: use 0 (off) or at least {MIN_ACCURACY_RTOL:g}")
    if acc > 0.0:
        chosen = [k for k in ACCURACY_CHOOSES if k in sc.overrides]
        if chosen:
            raise SceneError(f"accuracy.rtol = {acc:g} chooses {', '.join(ACCURACY_CHOOSES)}; do not also set "
                             f"{', '.join(chosen)}")
    if sc.observe.steady_window < sc.time.dt:
        raise SceneError(f"observe.steady_window = {sc.observe.steady_window} s must be at least one time step "
                         f"(time.dt = {sc.time.dt} s)")
    if sc.clamped:
        head_listed = [e for e in HEAD_EFFECTS if e in eff]
        if head_listed:
            raise SceneError(f"scene.effects: 'clamp' holds the head fixed, so it cannot be combined with "
                             f"{', '.join(head_listed)}")
        if sc.robot.n_flagella != 1:
            raise SceneError(f"robot.n_flagella = {sc.robot.n_flagella}: the 'clamp' scene drives exactly one "
                             "flagellum; set robot.n_flagella = 1")
        # (a fast clamp needs no refusal: every step is split so that it turns at most time.max_turn)


def inert_keys(sc: Scene) -> dict[str, str]:
    """Keys that do not enter this scene's model, each with the reason: a fit, a design search or a sweep that
    varies one is refused (it would vary nothing)."""
    out = {}
    if sc.medium.model == "viscous":
        for key in ("head.C1", "head.C2"):
            out[key] = (f"{key} does not enter medium.model = 'viscous' (the head is the exact Stokes sphere; C1, C2 "
                        "are the granular model's fitted factors)")
    return out


#: a helical flagellum needs at least this many edges per turn: an edge then spans an azimuth d <= 2 pi / 8, and
#: its chord's tan(pitch angle) is within 1 - sin(d/2)/(d/2) < 2.6% of the helix's
HELIX_EDGES_PER_TURN = 8


def _check_helix(sc: Scene) -> None:
    """Refuse a helical flagellum whose turns touch (|P| <= 2 r0) or that its edges cannot resolve."""
    fl = sc.flagellum
    P = fl.helix_pitch
    if P == 0.0:
        return
    if abs(P) <= 2.0 * fl.radius:
        raise SceneError(f"flagellum.helix_pitch = {P:g} m: its turns would overlap; |P| must exceed the "
                         f"flagellum's diameter 2 r0 = {2 * fl.radius:g} m")
    turn = _medium.helix_turn_length(sc.R_d, P)
    n_seg = flagellum_edge_count(fl.length, fl.edge_length)
    if fl.length / n_seg > turn / HELIX_EDGES_PER_TURN:
        raise SceneError(f"flagellum.helix_pitch = {P:g} m: one turn is {turn:.3g} m of flagellum, which its "
                         f"{fl.length / n_seg:.3g} m edges cannot resolve; use flagellum.edge_length <= "
                         f"{turn / HELIX_EDGES_PER_TURN:.3g} m ({HELIX_EDGES_PER_TURN} edges per turn) or a longer "
                         "|pitch|")


def _check_force_tol(sc: Scene) -> None:
    """Refuse a Newton tolerance the robot cannot be solved to: below its round-off floor (NEWTON_ROUNDOFFS times
    the round-off of its stiffest spring, where the solver stops whatever is asked) and tighter than the default.
    The default itself is always accepted (on a robot with stiff or thin parts it means the floor): recordings
    and scene files written out carry it, and they must stay readable."""
    tol = sc.numerics.force_tol
    if tol >= NumericsSection.force_tol:
        return                          # the check builds the network: only for the values it can refuse
    net = build_network(sc)
    roundoff, edge = net.residual_roundoff()
    floor = NEWTON_ROUNDOFFS * roundoff / force_scale(sc)
    if tol >= floor:
        return
    width = f"{1e3 * net.edge_rest_length[edge]:.3g} mm"
    spring = (f"the rigid parts, numerics.rigid_factor = {sc.numerics.rigid_factor:g}, over a {width} edge"
              if not net.edge_elastic[edge] else f"the flagellum over its {width} edges (flagellum.edge_length)")
    default = NumericsSection.force_tol
    raise SceneError(f"numerics.force_tol = {tol:g} cannot be met: this robot's residual is not resolved below "
                     f"{floor:.3g} of EI/L^2 ({NEWTON_ROUNDOFFS:g} round-offs of its stiffest spring: {spring}), "
                     f"where Newton stops; use >= {_round_up(floor)} or the default {default:g}"
                     + (" (which means the floor here)" if floor > default else ""))


def _round_up(x: float) -> str:
    """``x`` > 0 rounded up to two significant digits, as text (a bound to quote that is not below ``x``)."""
    step = 10.0 ** (math.floor(math.log10(x)) - 1)
    return f"{math.ceil(x / step * (1 - 1e-12)) * step:.2g}"


def _check_proportions(sc: Scene) -> None:
    """Refuse a robot whose smallest part vanishes next to its overall size (MIN_LENGTH_RATIO): its edge would
    be lost in the rounding of the node coordinates and the model would divide by a zero length."""
    parts = {"flagellum.length": sc.flagellum.length, "flagellum.edge_length": sc.flagellum.edge_length,
             "flagellum.radius": sc.flagellum.radius, "plate.diameter": sc.plate.diameter,
             "plate.thickness": sc.plate.thickness}
    if not sc.clamped:
        parts["head.radius"] = sc.head.radius
    largest = max(parts, key=parts.get)
    size = sc.flagellum.length + sc.plate.thickness + 0.5 * sc.plate.diameter + \
        (2.0 * sc.head.radius if not sc.clamped else 0.0)
    for key, value in parts.items():
        if value < MIN_LENGTH_RATIO * size:
            raise SceneError(f"{key} = {value:g} m is too small next to {largest} = {parts[largest]:g} m: every "
                             f"part of the robot must be at least {MIN_LENGTH_RATIO:g} of its overall size "
                             f"({size:.3g} m), i.e. >= {MIN_LENGTH_RATIO * size:.3g} m")


# ---------------------------------------------------------------- loading

def _sets_nothing(data: dict) -> bool:
    return all(isinstance(v, dict) and not v for v in data.values())


def scene_from_text(text: str, path: Path) -> Scene:
    """The scene in the TOML ``text`` of the file ``path`` (its stem names it unless it says ``scene.name``). A
    file that sets no key at all (empty, only comments, only empty tables) is refused: it would silently run on
    every default."""
    data = _toml_loads(text, str(path))
    if _sets_nothing(data):
        raise SceneError(f"scene file {short(str(path))} sets no keys (it is empty, or has only comments or empty "
                         "tables), so every value would be a default; start from a built-in scene "
                         "(flagbot scenes lists them and every key)")
    scene_table = data.setdefault("scene", {})
    if isinstance(scene_table, dict):
        scene_table.setdefault("name", path.stem)
    return scene_from_dict(data, source=str(path))


def load_scene(name_or_path: str | Path, overrides: dict[str, Any] | list[str] | None = None) -> Scene:
    """Load a built-in scene by name (``design1``) or a TOML file by path, then apply overrides.

    A file that sets no key at all (empty, only comments, only empty tables) is refused: it would silently run
    on every default.
    """
    path = resolve_scene_path(name_or_path)
    scene = scene_from_text(read_scene_text(path), path)
    if overrides:
        scene = scene.with_overrides(overrides)
    return scene
