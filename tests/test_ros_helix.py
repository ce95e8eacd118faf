"""sim_node takes the helix and medium keys like any other scene override: a helical robot in the fluid runs and
publishes its forward speed, and a wrong combination is refused at start-up in one error line naming the key."""
from ros_helpers import DISCOVERY_TIMEOUT, ChildProcess, Listener, NodeProcess

OVERRIDES = ["flagellum.length=0.05", "flagellum.helix_pitch=-0.03", "medium.model=viscous", "medium.mu=1.2"]


def _array(items):
    return "[" + ",".join(f'"{o}"' for o in items) + "]"


def test_a_helical_robot_in_the_fluid_swims_head_first(ros):
    proc = NodeProcess("flagbot_sim.ros.sim_node", "--ros-args", "-p", "scene:=design2",
                       "-p", f"scene_overrides:={_array(OVERRIDES)}", "-p", "real_time_factor:=2.0",
                       "-p", "initial_omega:=10.0")
    lis = Listener(ros)
    try:
        # a few simulated seconds of the helical robot, speed included: `speed` has no stamp, and the last one
        # received after a later /clock can be an earlier tick's (still queued), so the speeds read are those
        # published after the first /clock past 3 s
        lis.run_until(3.0)
        late = lis.since_clock("speed", 3.0)
        assert late, "no speed published after t = 3 s"
        # a left-handed helix turned forwards pushes the robot head first (v > 0), and nothing non-finite
        assert late[-1].data > 0
        assert not lis.non_finite
    finally:
        lis.close()
        code, out = proc.stop()
    assert code == 0 and "Traceback" not in out, out


def test_a_wrong_combination_is_refused_at_start_up():
    bad = ["medium.model=viscous",
           "scene.effects=['inertia','rft','head_drag','head_torque','motor','granular_yield']"]
    p = ChildProcess("-m", "flagbot_sim.ros.sim_node", "--ros-args", "-p", "scene:=design2",
                     "-p", f"scene_overrides:={_array(bad)}")
    code, out = p.wait(DISCOVERY_TIMEOUT)
    assert code == 2 and "Traceback" not in out, out
    errors = [line for line in out.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "scene.effects" in errors[0] and "viscous" in errors[0], out
