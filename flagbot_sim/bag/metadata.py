"""Run metadata: what is needed to reproduce a recorded run, and rosbag2's own metadata record."""
from __future__ import annotations

import datetime as _dt
import json
import os
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from ..cliutil import dumps  # strict JSON (a leaf module: no CLI, no ROS)
from .format import BagError


def package_version() -> str:
    """flagbot_sim's version: ``flagbot_sim.__version__`` of the imported source, else the installed metadata."""
    import flagbot_sim
    if getattr(flagbot_sim, "__version__", None):
        return str(flagbot_sim.__version__)
    try:
        from importlib.metadata import PackageNotFoundError, version
        try:
            return version("flagbot_sim")
        except PackageNotFoundError:
            pass
    except ImportError:
        pass
    xml = Path(__file__).resolve().parents[2] / "package.xml"
    m = re.search(r"<version>([^<]+)</version>", xml.read_text()) if xml.is_file() else None
    return m.group(1) if m else "unknown"


def source_revision() -> str:
    """``git describe`` of the source tree this package was imported from, or '' when not a checkout."""
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return ""
    import subprocess
    try:
        r = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty", "--abbrev=12"],
                           capture_output=True, text=True, timeout=5)
        return r.stdout.strip() if r.returncode == 0 else ""
    except (OSError, subprocess.SubprocessError):
        return ""


def _jsonable(o: Any) -> Any:
    """A parameter value as plain JSON data: numpy values as numbers/lists, anything JSON has no type for (the
    bytes of a byte-array parameter, ...) as its ``str``."""
    if o is None or isinstance(o, (bool, int, float, str)):
        return o
    if isinstance(o, Mapping):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if hasattr(o, "tolist"):                 # numpy array or scalar
        return _jsonable(o.tolist())
    return str(o)


@dataclass
class RunMetadata:
    """What is needed to reproduce a run: the scene file text, every parameter value, the package version.

    Stored as the MCAP metadata record ``flagbot_sim`` (string map): ``scene_toml``, ``parameters`` (JSON object),
    ``package_version``, ``source_revision``, ``created_utc``, ``command_line`` and any ``extra`` keys.
    """
    scene_toml: str = ""
    parameters: dict[str, Any] = field(default_factory=dict)
    package_version: str = field(default_factory=package_version)
    source_revision: str = field(default_factory=source_revision)
    created_utc: str = field(default_factory=lambda: _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    command_line: str = field(default_factory=lambda: " ".join(sys.argv))
    extra: dict[str, str] = field(default_factory=dict)

    _KEYS = ("scene_toml", "package_version", "source_revision", "created_utc", "command_line")

    def to_record(self) -> dict[str, str]:
        rec = {"package": "flagbot_sim",
               "parameters": dumps(_jsonable(self.parameters), sort_keys=True)}
        for k in self._KEYS:
            rec[k] = str(getattr(self, k))
        for k, v in self.extra.items():
            if k in rec:
                raise BagError(f"metadata key {k!r} is reserved")
            rec[k] = str(v)
        return rec

    @classmethod
    def from_record(cls, rec: Mapping[str, str]) -> "RunMetadata":
        try:
            params = json.loads(rec.get("parameters", "{}") or "{}")
        except json.JSONDecodeError as exc:
            raise BagError(f"metadata 'parameters' is not valid JSON: {exc}") from None
        known = set(cls._KEYS) | {"parameters", "package"}
        return cls(parameters=params, extra={k: v for k, v in rec.items() if k not in known},
                   **{k: rec.get(k, "") for k in cls._KEYS})


def rosbag2_serialized_metadata(file_name: str) -> str:
    """rosbag2's BagMetadata (version 9) as YAML. Counts and times are left at zero: rosbag2 takes them from the
    MCAP statistics; what matters is ``version: 9`` (QoS stored as strings) and ``ros_distro``."""
    distro = os.environ.get("ROS_DISTRO", "jazzy")
    return ("version: 9\nstorage_identifier: mcap\nduration:\n  nanoseconds: 0\nstarting_time:\n"
            "  nanoseconds_since_epoch: 0\nmessage_count: 0\ntopics_with_message_count: []\n"
            "compression_format: \"\"\ncompression_mode: \"\"\nrelative_file_paths:\n"
            f"  - {dumps(file_name)}\nfiles: []\ncustom_data: {{}}\nros_distro: {distro}\n")

