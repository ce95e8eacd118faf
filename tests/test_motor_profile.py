"""Motor-speed profiles (pure functions) and the cmd_profile node publishing them."""
import math

import pytest
from std_msgs.msg import Float64

from flagbot_sim.motor_profile import ProfileError, parse
from flagbot_sim.units import RPM

from ros_helpers import DISCOVERY_TIMEOUT, NodeProcess, spin_until


def test_steps_ramp_square_constant():
    p = parse("steps", ["50:2,100:3"], rpm=True)
    assert p.duration == 5.0
    assert p.value(0.0) == p.value(1.99) == pytest.approx(50 * RPM)
    assert p.value(2.0) == p.value(4.9) == p.value(9.0) == pytest.approx(100 * RPM)     # held after the end
    assert [(a, b) for a, b, _ in p.segments()] == [(0.0, 2.0), (2.0, 5.0)]
    r = parse("ramp", ["0", "10", "4"])
    assert r.value(1.0) == pytest.approx(2.5) and r.value(5.0) == 10.0
    sq = parse("square", ["0", "5", "2", "2"])
    assert [sq.value(t) for t in (0.5, 1.5, 2.5, 3.5, 4.5)] == [0.0, 5.0, 0.0, 5.0, 0.0]
    assert parse("constant", ["3"]).value(100.0) == 3.0
    looped = parse("steps", ["1:1,2:1"], loop=True)
    assert looped.value(2.5) == 1.0 and looped.value(3.5) == 2.0


@pytest.mark.parametrize("kind,args,word", [
    ("steps", ["50:abc"], "step duration"), ("steps", ["50"], "VALUE:SECONDS"), ("ramp", ["0", "1"], "FROM TO"),
    ("square", ["0", "1", "-2"], "positive"), ("constant", ["nan"], "finite"), ("wave", ["1"], "unknown profile"),
])
def test_bad_profiles_say_what_is_wrong(kind, args, word):
    with pytest.raises(ProfileError, match=word):
        parse(kind, args)


def test_cmd_profile_publishes_the_profile_and_exits_at_the_end(ros):
    node = ros
    got = []
    sub = node.create_subscription(Float64, "cmd_omega", lambda m: got.append(m.data), 50)
    proc = NodeProcess("flagbot_sim.ros.cmd_profile", "steps", "1.5:3.0,-2.5:1.0", "--rate", "20", "--exit-at-end",
                       "--quiet")
    try:
        spin_until(node, lambda: -2.5 in got, DISCOVERY_TIMEOUT + 5, "the second step")
        spin_until(node, lambda: not proc.alive(), 10, "cmd_profile to exit at the end")
    finally:
        code, out = proc.stop()
        node.destroy_subscription(sub)
    assert code == 0 and "Traceback" not in out, out
    assert set(got) == {1.5, -2.5} and got.index(-2.5) > got.index(1.5)
    assert all(math.isfinite(x) for x in got)
