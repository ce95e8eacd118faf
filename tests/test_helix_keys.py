"""The helix and medium keys through every tool, as users run them: `flagbot scenes` lists them with units and
ranges, sweeps / fit / optimize take them like any other key (and draw the groups on one figure), and a
combination the model cannot honour is refused in one `error:` line naming the key, exit status 2."""
import csv
import json

import pytest

from flagbot_sim.scene import load_scene

from cli_helpers import flagbot

VISCOUS = ["--set", "medium.model=viscous", "--set", "medium.mu=1.2"]


def test_flagbot_scenes_lists_the_keys_with_units_and_ranges():
    p = flagbot("scenes")
    assert p.returncode == 0, p.stderr
    lines = {line.split()[0]: line for line in p.stdout.splitlines() if line.strip().startswith(("flagellum.", "medium."))}
    assert " m " in lines["flagellum.helix_pitch"] and ">=-1000 <=1000" in lines["flagellum.helix_pitch"]
    assert "granular_rft|viscous" in lines["medium.model"]
    assert "Pa*s" in lines["medium.mu"]


@pytest.mark.parametrize("args,key", [
    (("steady", "design1", "--set", "flagellum.helix_pitch=0.004"), "flagellum.helix_pitch"),
    (("run", "design1", *VISCOUS, "--set",
      "scene.effects=['inertia','rft','head_drag','head_torque','motor','granular_yield']"), "scene.effects"),
    (("beam", "design1", "--set", "flagellum.helix_pitch=-0.05"), "flagellum.helix_pitch"),
    (("sweep", "design1", "--grid", "rpm=50", "--grid", "flagellum.helix_pitch=0,-0.05", "--out", "{tmp}/s"),
     "flagellum.helix_pitch"),
    (("sweep", "design1", *VISCOUS, "--grid", "head.C1=1,2", "--out", "{tmp}/s"), "head.C1"),
    (("fit", "design1", "{tmp}/data.csv", "--fit", "head.C2", *VISCOUS, "--out", "{tmp}/f"), "head.C2"),
    (("optimize", "design1", *VISCOUS, "--vary", "head.C1=0.5:5", "--out", "{tmp}/o"), "head.C1"),
    (("optimize", "design1", "--vary", "flagellum.helix_pitch=-0.01:0.01", "--grid-points", "5", "--engine",
      "serial", "--out", "{tmp}/o"), "flagellum.helix_pitch"),
])
def test_a_wrong_combination_is_one_error_line_naming_the_key(tmp_path, args, key):
    (tmp_path / "data.csv").write_text("n,omega_T_rpm,v\n2,100,1e-4\n")
    p = flagbot(*[a.format(tmp=tmp_path) for a in args])
    assert p.returncode == 2, (p.stdout, p.stderr)
    err = [line for line in p.stderr.splitlines() if line.startswith("error")]
    assert len(err) == 1 and err[0].startswith("error: ") and key in err[0], p.stderr
    assert "Traceback" not in p.stderr


def test_fitting_the_pitch_from_straight_flagella_asks_for_a_helical_start(tmp_path):
    """0 is apart from every helix (|P| > 2 r0): the fit refuses it before any model run, naming the key and how
    to start (it used to run once and fail on its first finite-difference step, naming a pitch the user never
    gave)."""
    (tmp_path / "data.csv").write_text("n,omega_T_rpm,v\n2,100,1e-4\n")
    p = flagbot("fit", "design1", str(tmp_path / "data.csv"), "--fit", "flagellum.helix_pitch", "--engine", "serial",
                "--out", str(tmp_path / "f"))
    assert p.returncode == 2, (p.stdout, p.stderr)
    err = [line for line in p.stderr.splitlines() if line.startswith("error")]
    assert len(err) == 1 and "--fit flagellum.helix_pitch: the start value is 0" in err[0], p.stderr
    assert "--set flagellum.helix_pitch=" in err[0] and "evaluation" not in p.stdout + p.stderr


def test_sweep_fit_and_optimize_take_the_keys(tmp_path):
    """A DER sweep over the handedness and the medium (with the comparison figure), a fit that recovers the
    pitch and viscosity behind synthetic data, and a design search over the pitch."""
    short = ["--set", "flagellum.length=0.05"]
    p = flagbot("sweep", "design2", *short, "--grid", "n=2", "--grid", "rpm=60,120",
                "--grid", "flagellum.helix_pitch=0.05,-0.05", "--grid", "medium.model=granular_rft,viscous",
                "--frameworks", "der", "--engine", "serial", "--quiet", "--out", str(tmp_path / "sw"))
    assert p.returncode == 0, p.stderr
    rows = list(csv.DictReader(open(tmp_path / "sw" / "results.csv")))
    assert len(rows) == 8 and all(r["error"] == "" for r in rows)
    v = {(r["flagellum.helix_pitch"], r["medium.model"], r["motor.omega_rpm"]): float(r["v"]) for r in rows}
    # the handedness decides the direction in both media: left-handed head first, right-handed backwards
    assert all(v[("-0.05", m, w)] > 0 > v[("0.05", m, w)] for m in ("granular_rft", "viscous") for w in ("60.0", "120.0"))
    assert (tmp_path / "sw" / "speed_by_group.png").stat().st_size > 0
    # data from the viscous left-handed points; the fit starts elsewhere and recovers both keys
    data = tmp_path / "data.csv"
    with open(data, "w") as f:
        f.write("n,omega_T_rpm,v,omega_h\n")
        for r in rows:
            if r["medium.model"] == "viscous" and r["flagellum.helix_pitch"] == "-0.05":
                f.write(f"2,{r['motor.omega_rpm']},{r['v']},{r['omega_h']}\n")
    p = flagbot("fit", "design2", str(data), *short, "--set", "medium.model=viscous", "--set", "medium.mu=1.0",
                "--set", "flagellum.helix_pitch=-0.04", "--fit", "flagellum.helix_pitch,medium.mu", "--engine",
                "serial", "--out", str(tmp_path / "fit"))
    assert p.returncode == 0, p.stderr
    est = {q["key"]: q["estimate"] for q in json.load(open(tmp_path / "fit" / "fit.json"))["parameters"]}
    assert est["flagellum.helix_pitch"] == pytest.approx(-0.05, rel=1e-4)
    assert est["medium.mu"] == pytest.approx(load_scene("design2").medium.mu, rel=1e-4)   # the sweep's viscosity
    p = flagbot("optimize", "design2", *short, *VISCOUS, "--vary", "flagellum.helix_pitch=-0.2:-0.02",
                "--grid-points", "4", "--max-evaluations", "12", "--engine", "serial", "--out", str(tmp_path / "o"))
    assert p.returncode == 0, p.stderr
    best = json.load(open(tmp_path / "o" / "optimize.json"))["optimum"]
    # the fastest pitch is inside the range (RFT's thrust per length peaks near a 45-degree helix), head first
    assert -0.2 < best["design"]["flagellum.helix_pitch"] < -0.02 and best["v"] > 0 and best["feasible"]


def test_the_group_figure_draws_one_curve_per_group_and_n():
    from flagbot_sim.sweep.plots import figure_groups
    rows = [{"framework": "der", "n": n, "L": 0.1, "omega_T_rpm": w, "v": 1e-3 * w * (1 + k) / n, "error": "",
             "flagellum.helix_pitch": p, "medium.model": m}
            for k, (p, m) in enumerate([(0.0, "granular_rft"), (-0.05, "granular_rft"), (-0.05, "viscous")])
            for n in (2, 3) for w in (50.0, 100.0)]
    fig = figure_groups(rows, ["flagellum.helix_pitch", "medium.model"])
    lines = fig.axes[0].get_lines()
    assert len(lines) == 6
    labels = {ln.get_label() for ln in lines}
    assert "helix_pitch -0.05, model viscous, n=3" in labels
    # each curve is its group's data, in mm/s
    line = next(ln for ln in lines if ln.get_label() == "helix_pitch -0.05, model viscous, n=3")
    assert list(line.get_ydata()) == pytest.approx([1e3 * 1e-3 * w * 3 / 3 for w in (50.0, 100.0)])
