"""DDS stays on this machine unless the user opts in. No rclpy import: the demo and the tests set this up
before anything initialises ROS.

Every process the package starts calls :func:`configure_dds` on its environment before ``rclpy.init``
(``runtime.ros_process`` does, and so do ``flagbot demo`` and the test suite), and the processes they start
inherit the result:

- ``ROS_AUTOMATIC_DISCOVERY_RANGE`` defaults to ``LOCALHOST`` when it is unset or empty.
- Unless the user opted in to the network, ``FASTRTPS_DEFAULT_PROFILES_FILE`` points to ``dds_loopback.xml``
  (shared memory + UDPv4 restricted to 127.0.0.1, discovery by unicast to 127.0.0.1). The discovery range is
  then set to ``SYSTEM_DEFAULT``, because under ``LOCALHOST`` rmw_fastrtps (Jazzy) appends a UDPv4 transport
  of its own with no interface restriction to whatever the profile says: measured with the profile and
  ``LOCALHOST``, sim_node still had a UDP socket on 0.0.0.0 and one on the external address. Under
  ``SYSTEM_DEFAULT`` the rmw leaves the profile's transports alone and every socket is bound to 127.0.0.1.
  ``OFF`` is kept as it is (no discovery at all).
- The range is switched only once the profile file has been read and parsed here: without the profile,
  ``SYSTEM_DEFAULT`` would be Fast DDS's default multicast discovery on every interface.

Opting in (documented in msg_docs/README.md): ``FLAGBOT_DDS_NETWORK=1`` leaves DDS to ROS's usual variables
(``ROS_AUTOMATIC_DISCOVERY_RANGE``, still defaulting to ``LOCALHOST``; set ``SUBNET`` to reach other machines);
so does a profile of the user's own in ``FASTRTPS_DEFAULT_PROFILES_FILE`` or ``FASTDDS_DEFAULT_PROFILES_FILE``
(the latter is read by Fast DDS 3 only; the 2.14 of the Jazzy wheels ignores it), or an RMW other than Fast DDS.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import MutableMapping

RANGE = "ROS_AUTOMATIC_DISCOVERY_RANGE"
NETWORK_OPT_IN = "FLAGBOT_DDS_NETWORK"
PROFILE_VARS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
LOOPBACK_PROFILE = Path(__file__).resolve().with_name("dds_loopback.xml")


def _is_ours(path: str) -> bool:
    try:
        return Path(path).resolve() == LOOPBACK_PROFILE
    except (OSError, ValueError):
        return False


def _profile_ok() -> bool:
    try:
        root = ET.parse(LOOPBACK_PROFILE).getroot()
    except (OSError, ET.ParseError):
        return False
    return root.tag.endswith("dds")


def configure_dds(env: MutableMapping[str, str] | None = None) -> str:
    """Apply the loopback-only default to ``env`` (default ``os.environ``); returns what was chosen, in words."""
    env = os.environ if env is None else env
    if not env.get(RANGE, "").strip():
        env[RANGE] = "LOCALHOST"
    if env.get(NETWORK_OPT_IN, "").strip() == "1":
        return f"DDS as configured by the environment ({NETWORK_OPT_IN}=1, {RANGE}={env[RANGE]})"
    foreign = [v for v in PROFILE_VARS if env.get(v, "").strip() and not _is_ours(env[v])]
    if foreign:
        return f"DDS as configured by {foreign[0]}={env[foreign[0]]} ({RANGE}={env[RANGE]})"
    rmw = env.get("RMW_IMPLEMENTATION", "").strip()
    if rmw and rmw != "rmw_fastrtps_cpp":
        return f"DDS as configured by {rmw} ({RANGE}={env[RANGE]}; the loopback profile is Fast DDS's)"
    if not _profile_ok():
        return f"DDS with {RANGE}={env[RANGE]} (the loopback profile {LOOPBACK_PROFILE} is missing or unreadable)"
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(LOOPBACK_PROFILE)
    env.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
    if env[RANGE] != "OFF":
        env[RANGE] = "SYSTEM_DEFAULT"
    return f"DDS on loopback only (flagbot profile; {NETWORK_OPT_IN}=1 to use the network)"


def loopback_only(env: MutableMapping[str, str]) -> bool:
    """Whether a process started with ``env`` keeps DDS on this machine: our profile in force, or LOCALHOST."""
    if env.get(NETWORK_OPT_IN, "").strip() == "1":
        return env.get(RANGE) in ("LOCALHOST", "OFF")
    profile = env.get("FASTRTPS_DEFAULT_PROFILES_FILE", "")
    if profile and _is_ours(profile):
        return env.get(RANGE) in ("SYSTEM_DEFAULT", "OFF", "LOCALHOST")
    return env.get(RANGE) in ("LOCALHOST", "OFF")
