"""Scene files: load, validate and override the parameters of one simulation.

A scene is a TOML file (stdlib ``tomllib``) with one table per section. Every key is declared once here, with
its unit, type and allowed range; anything else is an error that names the key and lists the valid ones. Values
are SI inside the program; the only non-SI key is ``motor.omega_rpm`` (the paper quotes motor speeds in rpm),
converted once by :attr:`Scene.omega_T`.

Scenes choose the physical effects they want in ``scene.effects``; the model builds only those
(see :mod:`flagbot_sim.physics.model`).
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from .physics.effects import EFFECT_TYPES

RPM = 2.0 * math.pi / 60.0  # rad/s per rpm

#: Effects a scene may list, with what each one adds to the model: the physics' one registry (an effect is one
#: class in physics.effects, plus its constants' keys in a section here)
EFFECTS: dict[str, str] = {name: cls.description for name, cls in EFFECT_TYPES.items()}
#: effects that need the head (the clamped scene holds it fixed)
HEAD_EFFECTS = tuple(name for name, cls in EFFECT_TYPES.items() if cls.on_head)


class SceneError(ValueError):
    """A scene file or override is invalid. The message names the key and the allowed values."""


def spec(unit: str = "", *, gt: float | None = None, ge: float | None = None, lt: float | None = None,
         le: float | None = None, doc: str = "", choices: tuple | None = None) -> dict:
    return {"unit": unit, "gt": gt, "ge": ge, "lt": lt, "le": le, "doc": doc, "choices": choices}


def _f(default, unit="", doc="", **bounds):
    return field(default=default, metadata=spec(unit, doc=doc, **bounds))


@dataclass(frozen=True)
class SceneSection:
    name: str = _f("unnamed", doc="scene name")
    description: str = _f("", doc="free text")
    effects: tuple = _f(("inertia", "rft", "head_drag", "head_torque", "motor"),
                        doc="physical effects to build, from: " + ", ".join(EFFECTS))
    preset: str = _f("default", doc="accuracy preset: discretisation applied on top of the scene file "
                                    "(overrides still win); see PRESETS")


@dataclass(frozen=True)
class RobotSection:
    n_flagella: int = _f(2, doc="number of flagella n", ge=1, le=12)


@dataclass(frozen=True)
class MotorSection:
    omega_rpm: float = _f(100.0, "rpm", "motor speed omega_T (clamped scene: the clamp's rotation speed)",
                          ge=-1.0e4, le=1.0e4)


@dataclass(frozen=True)
class TimeSection:
    dt: float = _f(1.0e-2, "s", "time step", gt=0.0, le=10.0)
    duration: float = _f(20.0, "s", "simulated time of a CLI run", gt=0.0)


@dataclass(frozen=True)
class FlagellumSection:
    length: float = _f(0.111, "m", "flagellum length L", gt=0.0)
    radius: float = _f(3.2e-3, "m", "flagellum radius r0", gt=0.0)
    edge_length: float = _f(4.11e-3, "m", "target length of a flagellum edge (rounded to fit L)", gt=0.0)
    youngs_modulus: float = _f(1.2e6, "Pa", "Young's modulus E", gt=0.0)
    poisson_ratio: float = _f(0.5, "", "Poisson's ratio (G = E / (2(1+nu)))", gt=-1.0, le=0.5)
    density: float = _f(1000.0, "kg/m^3", "density of flagella, plate and head", gt=0.0)


@dataclass(frozen=True)
class MediumSection:
    mu: float = _f(6.828, "Pa*s", "medium coefficient mu (RFT and Stokes terms)", gt=0.0)


@dataclass(frozen=True)
class HeadSection:
    radius: float = _f(0.02, "m", "head radius R_h", gt=0.0)
    C1: float = _f(2.420, "", "Stokes drag factor C1", ge=0.0)
    C2: float = _f(0.039, "", "Stokes torque factor C2", ge=0.0)


@dataclass(frozen=True)
class PlateSection:
    diameter: float = _f(0.04, "m", "plate diameter L_p; flagella sit at R_d = L_p/2", gt=0.0)
    thickness: float = _f(4.11e-3, "m", "plate thickness: the rigid axial stub each flagellum is clamped in",
                          gt=0.0)


@dataclass(frozen=True)
class NumericsSection:
    rigid_factor: float = _f(1.0e3, "", "stiffness of head/plate relative to the flagellum", ge=1.0, le=1.0e8)
    force_tol: float = _f(1.0e-7, "", "Newton tolerance on the force residual, relative to EI/L^2",
                          gt=0.0, lt=1.0)
    max_iterations: int = _f(25, "", "Newton iterations per attempt", ge=1, le=500)
    min_dt: float = _f(1.0e-6, "s", "smallest time step before a step is declared failed", gt=0.0)
    linear_solver: str = _f("auto", "", "Newton's linear solver: 'arrow' (banded flagella + Schur complement of "
                                        "the core), 'splu' (SuperLU), 'auto' (arrow when the network allows)",
                            choices=("auto", "arrow", "splu"))


@dataclass(frozen=True)
class ObserveSection:
    steady_window: float = _f(2.0, "s", "window over which steady-state rates are averaged", gt=0.0)
    steady_rtol: float = _f(1.0e-3, "", "relative change between windows counted as steady", gt=0.0)


@dataclass(frozen=True)
class GravitySection:
    g: tuple = _f((0.0, 0.0, -9.81), "m/s^2", "gravity vector (used only with the 'gravity' effect)")


SECTIONS: dict[str, type] = {
    "scene": SceneSection, "robot": RobotSection, "motor": MotorSection, "time": TimeSection,
    "flagellum": FlagellumSection, "medium": MediumSection, "head": HeadSection, "plate": PlateSection,
    "numerics": NumericsSection, "observe": ObserveSection, "gravity": GravitySection,
}

#: Accuracy presets: discretisation values applied on top of the scene file, under explicit overrides. Their
#: measured error (largest relative error of the steady outputs) and speed are in docs/accuracy.md: fast
#: <= 3.2%, default (the paper's discretisation) <= 1.5%, accurate <= 0.72% over the five study cases.
PRESETS: dict[str, dict[str, Any]] = {
    "fast": {"time.dt": 2.0e-2, "flagellum.edge_length": 8.22e-3},
    "default": {},
    "accurate": {"time.dt": 5.0e-3, "flagellum.edge_length": 2.055e-3},
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

    @property
    def EI(self) -> float:
        return math.pi / 4.0 * self.flagellum.youngs_modulus * self.flagellum.radius ** 4

    @property
    def eta_t(self) -> float:
        L, r0, mu = self.flagellum.length, self.flagellum.radius, self.medium.mu
        return 2.0 * math.pi * mu / (math.log(2.0 * L / r0) - 0.5)

    @property
    def eta_p(self) -> float:
        L, r0, mu = self.flagellum.length, self.flagellum.radius, self.medium.mu
        return 4.0 * math.pi * mu / (math.log(2.0 * L / r0) + 0.5)

    @property
    def head_drag_coefficient(self) -> float:
        """C1 * 6 pi mu R_h (N s/m)."""
        return self.head.C1 * 6.0 * math.pi * self.medium.mu * self.head.radius

    @property
    def head_torque_coefficient(self) -> float:
        """C2 * 8 pi mu R_h^3 (N m s)."""
        return self.head.C2 * 8.0 * math.pi * self.medium.mu * self.head.radius ** 3

    @property
    def relaxation_time(self) -> float:
        """Elasto-viscous time eta_p L^4 / EI (s): omega_bar = omega * this."""
        return self.eta_p * self.flagellum.length ** 4 / self.EI

    def normalise_omega(self, omega: float) -> float:
        return omega * self.relaxation_time

    def normalise_speed(self, v: float) -> float:
        return v * self.eta_p * self.flagellum.length ** 3 / self.EI

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


def _split_key(dotted: str) -> tuple[str, str]:
    if "." not in dotted:
        raise SceneError(f"override key {dotted!r} must be 'section.key'; sections: {', '.join(SECTIONS)}")
    section, key = dotted.split(".", 1)
    if section not in SECTIONS:
        raise SceneError(f"unknown section {section!r} in {dotted!r}; valid sections: {', '.join(SECTIONS)}")
    valid = [f.name for f in dataclasses.fields(SECTIONS[section])]
    if key not in valid:
        raise SceneError(f"unknown key {dotted!r}; valid keys in [{section}]: {', '.join(valid)}")
    return section, key


def parse_overrides(items: list[str]) -> dict[str, Any]:
    """Parse ``["flagellum.length=0.2", "scene.effects=['rft']"]`` with TOML value syntax.

    A bare word that is not valid TOML (``scene.name=foo``) is taken as a string.
    """
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise SceneError(f"override {item!r} must look like section.key=value")
        key, raw = item.split("=", 1)
        key = key.strip()
        _split_key(key)
        try:
            value = tomllib.loads(f"v = {raw.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw.strip()
        out[key] = value
    return out


def _check_value(section: str, f: dataclasses.Field, value: Any) -> Any:
    key = f"{section}.{f.name}"
    meta = f.metadata
    default = f.default
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise SceneError(f"{key} must be true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise SceneError(f"{key} must be an integer, got {value!r}")
    elif isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(f"{key} must be a number ({meta['unit'] or 'dimensionless'}), got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise SceneError(f"{key} must be finite, got {value!r}")
    elif isinstance(default, str):
        if not isinstance(value, str):
            raise SceneError(f"{key} must be a string, got {value!r}")
    elif isinstance(default, tuple):
        if not isinstance(value, (list, tuple)):
            raise SceneError(f"{key} must be a list, got {value!r}")
        value = tuple(value)
    if meta.get("choices") and value not in meta["choices"]:
        raise SceneError(f"{key} = {value!r} is not allowed; choose one of {', '.join(meta['choices'])}")
    for bound, op, word in (("gt", lambda a, b: a > b, ">"), ("ge", lambda a, b: a >= b, ">="),
                            ("lt", lambda a, b: a < b, "<"), ("le", lambda a, b: a <= b, "<=")):
        b = meta.get(bound)
        if b is not None and not op(value, b):
            unit = f" {meta['unit']}" if meta["unit"] else ""
            raise SceneError(f"{key} = {value!r}{unit} is out of range: must be {word} {b!r}{unit}")
    return value


def scene_from_dict(data: dict[str, Any], source: str = "", overrides: dict[str, Any] | None = None) -> Scene:
    """Validate a nested dict (as read from TOML) into a :class:`Scene`.

    Precedence, lowest first: the defaults declared here, the file's values, the accuracy preset
    (``scene.preset``), then ``overrides`` (``{"section.key": value}``).
    """
    overrides = dict(overrides or {})
    if not isinstance(data, dict):
        raise SceneError("a scene must be a table of sections")
    unknown = [s for s in data if s not in SECTIONS]
    if unknown:
        raise SceneError(f"unknown section(s) {', '.join(map(repr, unknown))}; valid sections: "
                         f"{', '.join(SECTIONS)}")
    merged: dict[str, dict[str, Any]] = {s: {} for s in SECTIONS}
    for s, values in data.items():
        if not isinstance(values, dict):
            raise SceneError(f"[{s}] must be a table of key = value")
        merged[s].update(values)
    preset_name = overrides.get("scene.preset", merged["scene"].get("preset", "default"))
    if preset_name not in PRESETS:
        raise SceneError(f"scene.preset = {preset_name!r} is not allowed; choose one of {', '.join(PRESETS)}")
    for dotted, value in list(PRESETS[preset_name].items()) + list(overrides.items()):
        s, k = _split_key(dotted)
        merged[s][k] = value
    sections = {}
    for s, cls in SECTIONS.items():
        fields = {f.name: f for f in dataclasses.fields(cls)}
        values = merged[s]
        bad = [k for k in values if k not in fields]
        if bad:
            raise SceneError(f"unknown key(s) {', '.join(f'{s}.{k}' for k in bad)}; valid keys in [{s}]: "
                             f"{', '.join(fields)}")
        kwargs = {k: _check_value(s, fields[k], v) for k, v in values.items()}
        sections[s] = cls(**kwargs)
    scene = Scene(**sections, source=source, file_data=data, overrides=overrides)
    _check_consistency(scene)
    return scene


def _check_consistency(sc: Scene) -> None:
    eff = sc.scene.effects
    for e in eff:
        if e not in EFFECTS:
            raise SceneError(f"scene.effects: unknown effect {e!r}; valid effects: {', '.join(EFFECTS)}")
    if len(set(eff)) != len(eff):
        raise SceneError(f"scene.effects lists an effect twice: {list(eff)}")
    fl = sc.flagellum
    if fl.radius >= fl.length:
        raise SceneError(f"flagellum.radius = {fl.radius} m must be smaller than flagellum.length = {fl.length} m")
    if 2.0 * fl.length / fl.radius <= math.exp(0.5):
        raise SceneError("flagellum.length / flagellum.radius is too small for resistive-force theory "
                         f"(needs log(2L/r0) > 1/2, got 2L/r0 = {2 * fl.length / fl.radius:.3g})")
    if fl.edge_length > fl.length:
        raise SceneError(f"flagellum.edge_length = {fl.edge_length} m must not exceed flagellum.length = "
                         f"{fl.length} m")
    if fl.length / fl.edge_length > 20000:
        raise SceneError(f"flagellum.edge_length = {fl.edge_length} m gives more than 20000 edges per flagellum")
    if sc.numerics.min_dt >= sc.time.dt:
        raise SceneError(f"numerics.min_dt = {sc.numerics.min_dt} s must be smaller than time.dt = {sc.time.dt} s")
    if len(sc.gravity.g) != 3 or not all(isinstance(x, (int, float)) for x in sc.gravity.g):
        raise SceneError(f"gravity.g must be a list of 3 numbers (m/s^2), got {list(sc.gravity.g)!r}")
    if sc.clamped:
        head_listed = [e for e in HEAD_EFFECTS if e in eff]
        if head_listed:
            raise SceneError(f"scene.effects: 'clamp' holds the head fixed, so it cannot be combined with "
                             f"{', '.join(head_listed)}")
        if sc.robot.n_flagella != 1:
            raise SceneError(f"robot.n_flagella = {sc.robot.n_flagella}: the 'clamp' scene drives exactly one "
                             "flagellum; set robot.n_flagella = 1")


# ---------------------------------------------------------------- loading

def builtin_scenes() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("flagbot_sim.scenes").iterdir()
                  if p.name.endswith(".toml"))


def resolve_scene_path(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if not p.exists():
            raise SceneError(f"scene file {str(p)!r} does not exist")
        return p
    candidate = resources.files("flagbot_sim.scenes") / f"{name_or_path}.toml"
    if candidate.is_file():
        return Path(str(candidate))
    raise SceneError(f"unknown scene {str(name_or_path)!r}: not a file, and not a built-in scene "
                     f"({', '.join(builtin_scenes())})")


def node_overrides(n_flagella: int, scene_overrides) -> list[str]:
    """Overrides as the ROS nodes take them: ``scene_overrides`` entries, then n_flagella unless it is 0."""
    extra = [str(o) for o in scene_overrides if str(o).strip()]
    if n_flagella:
        extra.append(f"robot.n_flagella={int(n_flagella)}")
    return extra


def load_scene(name_or_path: str | Path, overrides: dict[str, Any] | list[str] | None = None) -> Scene:
    """Load a built-in scene by name (``design1``) or a TOML file by path, then apply overrides."""
    path = resolve_scene_path(name_or_path)
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML: {exc}") from None
    data.setdefault("scene", {}).setdefault("name", path.stem)
    scene = scene_from_dict(data, source=str(path))
    if overrides:
        scene = scene.with_overrides(overrides)
    return scene
