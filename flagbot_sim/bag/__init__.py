"""MCAP recordings in rosbag2's layout: write, read (also damaged files), recover, and run metadata.

No ROS import, no command line, no flagbot topic name here: the recorder/replay nodes in :mod:`flagbot_sim.ros`
do the DDS side and hand serialized (CDR) bytes to this package, the analysis tools decode with ``mcap_ros2``
alone, and callers pass the topic names they look for. One module per concern, each importing only the ones
above it in this list:

- :mod:`.format`   constants of the layout (profile ``ros2``, ``ros2msg`` schemas, ``cdr``) and the errors;
- :mod:`.schema`   message definitions as rosbag2 stores them, header stamps read from CDR bytes;
- :mod:`.qos`      QoS profiles in rosbag2's version-9 YAML;
- :mod:`.metadata` :class:`RunMetadata` (scene, parameters, version) and rosbag2's own metadata record;
- :mod:`.writer`   :class:`BagWriter`: chunked, compressed, flushed often enough to survive a SIGKILL;
- :mod:`.reader`   :class:`BagReader`, :func:`scan` and :func:`recover`, record by record, tolerating damage;
- :mod:`.lost`     messages lost before they reached the recorder, from the publishers' sequence numbers;
- :mod:`.lookup`   topics by relative name (:func:`find_topic`), log time -> simulation time (:class:`SimTimeMap`),
  a decoded message's header stamp in seconds (:func:`header_seconds`).
"""
from .format import (DEFAULT_CHUNK_SIZE, DEFAULT_FLUSH_INTERVAL, RUN_METADATA_NAME, BagError, BagWriteError,
                     InterfaceNotFound, NotMcapError)
from .lookup import SimTimeMap, find_topic, header_seconds, namespace_of
from .metadata import RunMetadata, package_version, source_revision
from .qos import QosInfo, qos_from_yaml, qos_to_yaml
from .reader import BagMessage, BagReader, Damage, ScanReport, TopicInfo, recover, scan
from .schema import cdr_header_stamp_ns, has_header, message_definition, normalize_type, split_type
from .writer import BagWriter, TopicStats, WriteSummary

__all__ = ["BagError", "BagWriteError", "NotMcapError", "InterfaceNotFound", "BagWriter", "BagReader", "BagMessage",
           "RunMetadata", "ScanReport", "Damage", "TopicInfo", "TopicStats", "QosInfo", "WriteSummary",
           "message_definition", "normalize_type", "split_type", "has_header", "cdr_header_stamp_ns", "qos_to_yaml",
           "qos_from_yaml", "scan", "recover", "find_topic", "namespace_of", "header_seconds", "SimTimeMap",
           "package_version", "source_revision", "DEFAULT_FLUSH_INTERVAL", "DEFAULT_CHUNK_SIZE", "RUN_METADATA_NAME"]
