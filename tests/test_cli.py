"""The command line, run as users run it: a separate process."""
import json

import pytest
from cli_helpers import flagbot


def test_run_json_reports_the_documented_keys():
    p = flagbot("run", "design2", "--duration", "0.3", "--set", "flagellum.length=0.05", "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    for key in ("omega_T", "omega_h", "omega_t", "v", "steps", "newton_iterations", "wall_seconds",
                "real_time_factor"):
        assert key in out
    assert out["steps"] == 30 and out["omega_T"] == pytest.approx(100 * 2 * 3.141592653589793 / 60)
    assert p.stderr == ""            # no progress bar in JSON mode


def test_clamped_run_reports_force_torque_and_tip():
    p = flagbot("run", "clamped_flagellum", "--duration", "0.2", "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    # the medium resists the rotation at every instant (Fx changes sign during start-up: while the rod bends,
    # its segments slide towards the base and tangential drag pushes them away; at steady state it is thrust)
    assert out["Tx"] < 0 and len(out["tip"]) == 3 and isinstance(out["Fx"], float)
    # the tip starts near (L, R_d, 0) in the co-rotating frame
    assert out["tip"][0] == pytest.approx(0.111, abs=5e-3) and out["tip"][1] == pytest.approx(0.02, abs=5e-3)


def test_human_readable_run_shows_progress_and_summary():
    p = flagbot("run", "design1", "--duration", "0.1", "--set", "flagellum.length=0.05")
    assert p.returncode == 0
    assert "omega_h" in p.stdout and "real-time factor" in p.stdout
    assert "%" in p.stderr and "eta" in p.stderr       # the progress bar


def test_bad_input_is_a_one_line_error_naming_the_key():
    p = flagbot("run", "design1", "--set", "flagellum.youngs_modulus=-5")
    assert p.returncode == 2
    assert p.stderr.strip().startswith("error: flagellum.youngs_modulus")
    assert "Traceback" not in p.stderr
