"""DDS stays on this machine by default: a running sim_node (and this test process's probe node, which talks to
it) binds no UDP/TCP socket to anything but loopback, and the two still discover each other and communicate.

The environment logic of flagbot_sim/ros/dds.py is checked on plain dicts: no test widens discovery."""
from rosgraph_msgs.msg import Clock

from flagbot_sim.ros import dds

from ros_helpers import DISCOVERY_TIMEOUT, NodeProcess, inet_sockets, is_loopback, spin_until


def test_sim_node_and_probe_bind_dds_to_loopback_only_and_still_talk(ros):
    proc = NodeProcess("flagbot_sim.ros.sim_node", "--ros-args", "-p", "scene:=design2",
                       "-p", "initial_omega:=3.0")
    got = []
    sub = ros.create_subscription(Clock, "/clock", got.append, 10)
    try:
        # discovery and data both work through the profile: messages from the other process arrive
        spin_until(ros, lambda: len(got) >= 5, DISCOVERY_TIMEOUT, "/clock from sim_node")
        node_sockets = inet_sockets(proc.pid)
        own_sockets = inet_sockets()
    finally:
        ros.destroy_subscription(sub)
        code, out = proc.stop()
    assert code == 0, out
    for who, socks in (("sim_node", node_sockets), ("the probe", own_sockets)):
        print(who, sorted(socks))       # the measured list, for the record (pytest -s)
        # the listing works (Fast DDS's UDP locators are there), and every one of them is on loopback
        assert any(proto == "udp" and is_loopback(addr) for proto, addr, _ in socks), (who, socks)
        exposed = [s for s in socks if not is_loopback(s[1])]
        assert not exposed, f"{who} has sockets beyond loopback: {exposed}"


def test_loopback_profile_is_the_default_and_every_opt_in_is_respected():
    env = {}
    assert "loopback only" in dds.configure_dds(env)
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(dds.LOOPBACK_PROFILE) and dds.LOOPBACK_PROFILE.is_file()
    # the rmw must not add its own unrestricted UDP transport (it does under LOCALHOST): the profile rules
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT" and dds.loopback_only(env)
    again = dict(env)
    dds.configure_dds(again)                        # a child inheriting it keeps it unchanged
    assert again == env
    off = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"}
    dds.configure_dds(off)
    assert off["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "OFF"
    # opting in: the variable, a profile of the user's own, another RMW. The range still defaults to LOCALHOST
    for opt_in in ({"FLAGBOT_DDS_NETWORK": "1"}, {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/my_profile.xml"},
                   {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/my_profile.xml"},
                   {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}):
        env = dict(opt_in)
        dds.configure_dds(env)
        assert env == {**opt_in, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, opt_in
        assert dds.loopback_only(env)
        env = dict(opt_in, ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET")
        dds.configure_dds(env)
        assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SUBNET" and not dds.loopback_only(env)


def test_a_missing_profile_never_turns_into_default_discovery(monkeypatch, tmp_path):
    # without the profile, SYSTEM_DEFAULT would be Fast DDS's multicast discovery on every interface
    monkeypatch.setattr(dds, "LOOPBACK_PROFILE", tmp_path / "missing.xml")
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    assert "missing" in dds.configure_dds(env)
    assert env == {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    (tmp_path / "missing.xml").write_text("<dds><profiles>")      # truncated: not XML
    env = {}
    dds.configure_dds(env)
    assert env == {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
