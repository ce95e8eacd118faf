"""QoS profiles in rosbag2's version-9 YAML (the channel metadata ``offered_qos_profiles``)."""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Iterable

_INFINITE_NS = 0x7FFFFFFFFFFFFFFF  # RMW_DURATION_INFINITE


@dataclass(frozen=True)
class QosInfo:
    """The parts of a QoS profile a recorder/replayer needs (names as in rosbag2's YAML, lower case)."""
    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    liveliness: str = "automatic"
    deadline_ns: int = _INFINITE_NS
    lifespan_ns: int = _INFINITE_NS
    liveliness_lease_ns: int = _INFINITE_NS


def _yaml_duration(ns: int) -> str:
    ns = max(0, min(int(ns), _INFINITE_NS))
    return f"\n    sec: {ns // 1_000_000_000}\n    nsec: {ns % 1_000_000_000}"


def qos_to_yaml(profiles: Iterable[QosInfo]) -> str:
    """rosbag2 (metadata version 9) serialisation of the publishers' offered QoS profiles."""
    items = []
    for q in profiles:
        items.append(f"- history: {q.history}\n  depth: {q.depth}\n  reliability: {q.reliability}\n"
                     f"  durability: {q.durability}\n  deadline:{_yaml_duration(q.deadline_ns)}\n"
                     f"  lifespan:{_yaml_duration(q.lifespan_ns)}\n  liveliness: {q.liveliness}\n"
                     f"  liveliness_lease_duration:{_yaml_duration(q.liveliness_lease_ns)}\n"
                     f"  avoid_ros_namespace_conventions: false")
    return "\n".join(items)


_QOS_NAMES = {  # version-8 files store enum values
    "history": {0: "system_default", 1: "keep_last", 2: "keep_all", 3: "unknown"},
    "reliability": {0: "system_default", 1: "reliable", 2: "best_effort", 3: "unknown", 4: "best_available"},
    "durability": {0: "system_default", 1: "transient_local", 2: "volatile", 3: "unknown", 4: "best_available"},
    "liveliness": {0: "system_default", 1: "automatic", 3: "manual_by_topic", 4: "unknown", 5: "best_available"},
}


def qos_from_yaml(text: str) -> list[QosInfo]:
    """Parse ``offered_qos_profiles`` (version 8 or 9) loosely: policies and depth, one entry per publisher."""
    out = []
    for block in re.split(r"^- ", text or "", flags=re.MULTILINE):
        if not block.strip():
            continue
        kw = {}
        for key in ("history", "reliability", "durability", "liveliness"):
            m = re.search(rf"^\s*{key}:\s*(\S+)", block, re.MULTILINE)
            if m:
                v = m.group(1).strip("'\"")
                kw[key] = _QOS_NAMES[key].get(int(v), "unknown") if v.isdigit() else v.lower()
        m = re.search(r"^\s*depth:\s*(\d+)", block, re.MULTILINE)
        if m:
            kw["depth"] = int(m.group(1))
        out.append(QosInfo(**kw))
    return out

