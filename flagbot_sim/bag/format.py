"""The MCAP profile rosbag2 writes, as constants, and the errors of the bag package.

File layout, as rosbag2 (Jazzy) writes it (see ../shared/ROS_NOTES.md):

- header profile ``ros2``; one schema per message type, named ``pkg/msg/Type``, encoding ``ros2msg``, holding the
  type's full definition (:mod:`.schema`);
- one channel per topic, message encoding ``cdr``, channel metadata ``offered_qos_profiles`` (rosbag2's version-9
  YAML, :mod:`.qos`) and ``topic_type_hash`` when known;
- message log time = receive time, publish time = the ``std_msgs/Header`` stamp for types whose first field is a
  header (read straight from the CDR bytes), else the receive time;
- a ``rosbag2`` metadata record (``serialized_metadata``, version 9) written at the *start*, so that a file that
  never got closed still tells rosbag2 how to parse the QoS strings, and a ``flagbot_sim`` metadata record with
  the scene, all parameters and the package version (:mod:`.metadata`).
"""
from __future__ import annotations

MCAP_MAGIC = b"\x89MCAP0\r\n"
PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
#: name of the metadata record with the scene, parameters and package version
RUN_METADATA_NAME = "flagbot_sim"
#: name of the metadata record rosbag2 reads (key ``serialized_metadata``)
ROSBAG2_METADATA_NAME = "rosbag2"
RECOVERY_METADATA_NAME = "flagbot_sim.recovery"
LIBRARY = "flagbot_sim.bag"

#: chunks are closed at this size even between flushes (rosbag2 uses 768 KiB; smaller = less lost on a crash)
DEFAULT_CHUNK_SIZE = 256 * 1024
#: a chunk is closed and flushed to the OS at least this often (s): the most a SIGKILL can lose
DEFAULT_FLUSH_INTERVAL = 0.1


class BagError(Exception):
    """A recording cannot be read or written. The message says why, in terms a user can act on."""


class BagWriteError(BagError, OSError):
    """A recording cannot be created or written (no such directory, no permission, disk full, file too large).
    Both a BagError and an OSError, so either ``except`` clause catches it."""


class NotMcapError(BagError):
    """The file is not an MCAP file at all."""


class InterfaceNotFound(BagError):
    """The .msg definition of a type is not installed."""

