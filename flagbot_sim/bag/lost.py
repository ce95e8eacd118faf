"""Messages lost before they reached the recorder, counted from the publishers' sequence numbers.

Every DDS writer numbers its samples 1, 2, 3, ... (rmw_fastrtps passes the number on as the message info's
``publication_sequence_number``); a number skipped between two samples the recorder took is a message that never
reached it: overwritten in a KEEP_LAST history (the publisher's, when the recorder's process did not acknowledge in
time, or the recorder's subscription, when its executor fell behind) or dropped by a best-effort transport.
rosbag2 reports the same from its ``message_lost`` QoS event; with these rclpy/Fast DDS wheels that event does not
fire for a history overflow (tried: reliable and best effort, a slow callback and a small depth), so the numbers
are the measure.

The message info does not say which writer sent a sample, and the numbers are per writer. A topic with one
publisher (every flagbot topic: sim_node publishes them) is counted exactly. With several, each sample is given to
the stream whose last number is the largest below it (a writer's numbers only grow), a new stream when none is
below: exact while the writers' numbers do not cross, a lower bound when they do. Messages published before the
recorder's subscription matched are not lost: counting starts at the first number taken from each writer; and
messages lost after the last one taken from a writer leave no gap to see (a loss is counted when the next sample
arrives).

No DDS here: :class:`LostCounter` takes the numbers, the recorder feeds it (``flagbot_sim.ros.recorder``).
"""
from __future__ import annotations

import json
from typing import Mapping

#: metadata record written when a recording is closed: ``counts`` = JSON {topic: messages lost}, ``method``
LOST_METADATA_NAME = "flagbot_sim.lost_messages"
METHOD = "gaps in publication sequence numbers (per writer)"
#: writers remembered per topic (a publisher that went away leaves a stream; the least recently fed is dropped)
MAX_STREAMS = 64


class GapCounter:
    """Lost messages of one topic from the publication sequence numbers of the samples taken, in taking order."""

    def __init__(self, max_streams: int = MAX_STREAMS):
        self._last: list[int] = []        # per writer stream: the last number taken, most recently fed last
        self.max_streams = max_streams
        self.lost = 0
        self.taken = 0
        self.unnumbered = 0               # samples without a usable number (another rmw)
        self.warned = False               # the recorder logged the first loss

    def add(self, seq) -> int:
        """Count one sample numbered ``seq``; returns how many messages were lost just before it."""
        self.taken += 1
        if not isinstance(seq, int) or isinstance(seq, bool) or seq <= 0:
            self.unnumbered += 1
            return 0
        best = -1
        for i, last in enumerate(self._last):
            if last < seq and (best < 0 or last > self._last[best]):
                best = i
        if best < 0:                      # no stream below: a writer not seen yet
            if len(self._last) >= self.max_streams:
                del self._last[0]
            self._last.append(seq)
            return 0
        gap = seq - self._last.pop(best) - 1
        self._last.append(seq)
        self.lost += gap
        return gap


class LostCounter:
    """:class:`GapCounter` per topic."""

    def __init__(self):
        self.topics: dict[str, GapCounter] = {}

    def add(self, topic: str, seq) -> int:
        c = self.topics.get(topic)
        if c is None:
            c = self.topics[topic] = GapCounter()
        return c.add(seq)

    def first_loss(self, topic: str, seq) -> bool:
        """:meth:`add`; True only when this sample shows the topic's first loss (for a warning, once)."""
        if not self.add(topic, seq) or self.topics[topic].warned:
            return False
        self.topics[topic].warned = True
        return True

    def counts(self) -> dict[str, int]:
        """topic -> messages lost, for every topic that had a message."""
        return {t: c.lost for t, c in sorted(self.topics.items())}

    @property
    def total(self) -> int:
        return sum(c.lost for c in self.topics.values())

    def to_record(self) -> dict[str, str]:
        return {"counts": json.dumps(self.counts(), sort_keys=True), "total": str(self.total), "method": METHOD}


def counts_from_record(rec: Mapping[str, str] | None) -> dict[str, int] | None:
    """The {topic: lost} of a :data:`LOST_METADATA_NAME` record; None without one (or an unreadable one)."""
    if rec is None:
        return None
    try:
        counts = json.loads(rec.get("counts", ""))
    except (json.JSONDecodeError, TypeError):
        return None
    if not isinstance(counts, dict):
        return None
    return {str(k): int(v) for k, v in counts.items() if isinstance(v, int) and not isinstance(v, bool)}
