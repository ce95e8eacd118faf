"""Finding recorded topics by relative name, and recorded time -> simulation time. Names are passed in: this
package knows no flagbot topic."""
from __future__ import annotations

from typing import Any, Iterable


def find_topic(topics: Iterable[str], name: str, namespace: str | None = None) -> str | None:
    """The recorded topic for a relative name (e.g. ``omega_h``) in ``namespace`` (default: the only/first
    namespace that has it), or for an absolute one (``/clock``); None when not recorded."""
    topics = list(topics)
    if name.startswith("/"):
        return name if name in topics else None
    if namespace is not None:
        t = namespace.rstrip("/") + "/" + name
        t = t if t.startswith("/") else "/" + t
        return t if t in topics else None
    # prefer the shortest (/bot/omega_h over /bot/beam/omega_h), then the first by name
    cands = sorted((t for t in topics if t == "/" + name or t.endswith("/" + name)), key=lambda t: (t.count("/"), t))
    return cands[0] if cands else None


def namespace_of(topic: str, name: str) -> str:
    """``/bot`` for (``/bot/omega_h``, ``omega_h``); '' when ``topic`` is not ``name`` in some namespace."""
    return topic[: -len(name) - 1] if topic.endswith("/" + name) else ""


class SimTimeMap:
    """Map log (receive) time to simulation time by interpolating recorded rosgraph_msgs/Clock messages."""

    def __init__(self, log_ns: list[int], clock_ns: list[int]):
        self.log_ns = log_ns
        self.clock_ns = clock_ns

    @classmethod
    def from_rows(cls, rows: Iterable[tuple[int, int, Any]]) -> "SimTimeMap":
        """From decoded Clock messages (:meth:`BagReader.decoded` rows)."""
        return cls([lt for lt, _, _ in rows], [m.clock.sec * 1_000_000_000 + m.clock.nanosec for _, _, m in rows])

    def __bool__(self):
        return bool(self.log_ns)

    def __call__(self, log_ns):
        import numpy as np
        return np.interp(np.asarray(log_ns, dtype=float), np.asarray(self.log_ns, dtype=float),
                         np.asarray(self.clock_ns, dtype=float)) * 1e-9


def header_seconds(msg) -> float:
    """The header stamp of a decoded message, in seconds."""
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
