"""`python -m flagbot_sim beam ...`: the numbers it prints are the library's, in the units it says."""
import json

import pytest

from flagbot_sim.beam import BeamParams, solve_balance
from flagbot_sim.cli import main
from flagbot_sim.scene import load_scene
from flagbot_sim.units import RPM

KEYS = {"omega_T", "omega_h", "omega_t", "v_h", "F_p", "F_x", "w_tip_over_L", "converged"}


def test_json_output_is_one_list_with_the_library_values(capsys):
    code = main(["beam", "design2", "--set", "robot.n_flagella=3", "--omega-rpm", "50, 100", "--regime",
                 "nlb-nohead", "--json"])
    rows = json.loads(capsys.readouterr().out)
    assert code == 0 and isinstance(rows, list) and len(rows) == 2
    params = BeamParams.from_scene(load_scene("design2", ["robot.n_flagella=3"]))
    for row, rpm in zip(rows, (50, 100)):
        assert KEYS <= set(row) and row["converged"] is True
        assert row["omega_T"] == pytest.approx(rpm * RPM, rel=1e-12)      # rad/s, not rpm
        ref = solve_balance(params, rpm * RPM, "nlb-nohead")
        for key in KEYS - {"converged"}:
            assert row[key] == pytest.approx(getattr(ref, key), rel=1e-9)
        assert row["omega_h_rpm"] == pytest.approx(ref.omega_h / RPM)


def test_table_lists_every_motor_speed_in_rad_s_and_rpm(capsys):
    assert main(["beam", "design1", "--omega-rpm", "50,100,150", "--regime", "lb"]) == 0
    out = capsys.readouterr().out
    ref = solve_balance(BeamParams.from_scene(load_scene("design1")), 150 * RPM, "lb")
    lines = out.splitlines()
    assert "regime lb" in lines[0] and "n = 2" in lines[0]
    assert len(lines) == 3 + 3
    last = lines[-1]
    assert f"{ref.omega_h:10.5f} ({ref.omega_h / RPM:8.3f})" in last and f"{ref.v_h:11.4e}" in last


def test_default_motor_speed_is_the_scenes(capsys):
    assert main(["beam", "design1", "--set", "motor.omega_rpm=75", "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)
    assert row["omega_T"] == pytest.approx(75 * RPM) and row["regime"] == "nlb"


@pytest.mark.parametrize("argv, needle", [
    (["beam", "design1", "--omega-rpm", "50,fast"], "--omega-rpm"),
    (["beam", "design1", "--set", "head.C2=0"], "head.C2"),
    (["beam", "design1", "--set", "robot.n_flagela=3"], "robot.n_flagela"),
])
def test_bad_input_is_a_one_line_error(capsys, argv, needle):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and needle in err and "\n" not in err


def test_a_clamped_scene_is_refused_with_the_reason(capsys):
    # the balance solves the free robot's head torque and drag balance; the clamped scene holds its head
    assert main(["beam", "clamped_flagellum", "--json"]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert captured.out == "" and err.startswith("error: beam: scene 'clamped_flagellum'") and "\n" not in err
    assert "head is held fixed" in err and "free robot" in err


def test_json_is_strict_even_for_a_failed_point(capsys, monkeypatch):
    # a point the balance could not solve carries NaN; the JSON writes null where Python's json writes NaN
    import flagbot_sim.commands.beam as beam_cli

    class Failed:
        converged = False

        def to_dict(self):
            return {"omega_T": 1.0, "omega_h": float("nan"), "v_h": float("inf"), "converged": False}
    monkeypatch.setattr(beam_cli, "solve_balance_curve", lambda *a, **k: [Failed()])
    assert main(["beam", "design1", "--json"]) == 1
    (row,) = json.loads(capsys.readouterr().out, parse_constant=lambda c: pytest.fail(f"{c} in the JSON"))
    assert row["omega_h"] is None and row["v_h"] is None and row["omega_T"] == 1.0
