"""The example data of `flagbot fit` (data/*.csv, docs/data.md): what the files hold is what the documented
script makes (the fit's own steady-state model at the paper's constants, plus the stated scatter), and the
documented command runs on them and gives back the constants they were made with."""
import csv
import importlib.util
import json

import pytest

from cli_helpers import ROOT, flagbot

DATA = ROOT / "data"


def _script():
    spec = importlib.util.spec_from_file_location("make_fit_data", DATA / "make_fit_data.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _read(name):
    with open(DATA / name, newline="") as f:
        return list(csv.reader(f))


def test_the_shipped_rows_are_the_model_plus_the_documented_scatter():
    make = _script()
    assert sorted(p.name for p in DATA.glob("*.csv")) == sorted(make.FILES)
    speeds = {}
    for name, (scene, n, seed) in make.FILES.items():
        header, *rows = _read(name)
        assert header == make.HEADER
        again = make.synthetic_rows(scene, n, seed)
        assert len(rows) == len(again) == len(make.RPMS)
        for got, want in zip(rows, again):
            assert got[:2] == [str(n), str(want[1])] and got[6] == want[6] and got[6].startswith("synthetic: ")
            # 4 significant digits of the same numbers (else: the model changed, rerun data/make_fit_data.py)
            for k in (2, 3, 4, 5):
                assert float(got[k]) == pytest.approx(float(want[k]), rel=1e-3), (name, got, want)
        # the scatter is there and of the stated size: |measured - model| within 4 std, not all zero
        model = make.model_values(scene, n)
        z = [(float(r[2]) - m["v"]) / float(r[3]) for r, m in zip(rows, model)]
        assert max(map(abs, z)) < 4 and max(map(abs, z)) > 0.3
        assert all(float(r[3]) == pytest.approx(make.NOISE * abs(m["v"]), rel=0.01) for r, m in zip(rows, model))
        speeds[scene, n] = [m["v"] for m in model]
    # the paper's two designs: more flagella are slower in design 1, faster in design 2 (from 100 rpm here)
    assert all(a > b for a, b in zip(speeds["design1", 2], speeds["design1", 3]))
    fast = [i for i, r in enumerate(make.RPMS) if r >= 100]
    assert all(speeds["design2", 3][i] > speeds["design2", 2][i] for i in fast)


def test_the_documented_fit_command_recovers_the_constants_the_rows_were_made_with(tmp_path):
    """docs/data.md's command: C1, C2 and mu from a wrong start, on the n = 2 rows, predicting the n = 3 ones."""
    truth = {"head.C1": 2.420, "head.C2": 0.039, "medium.mu": 6.828}       # scenes/design1.toml (the paper's)
    p = flagbot("fit", "design1", str(DATA / "design1_n2.csv"), "--fit", "head.C1,head.C2,medium.mu",
                "--set", "head.C1=1", "--set", "head.C2=0.1", "--set", "medium.mu=4",
                "--predict", str(DATA / "design1_n3.csv"), "--out", str(tmp_path / "d1"), "--json", "--quiet",
                timeout=900)
    assert p.returncode == 0, p.stdout + p.stderr
    res = json.loads(p.stdout)
    assert res["identified"] and res["converged"]
    for e in res["parameters"]:
        lo, hi = e["ci95"]
        assert lo < truth[e["key"]] < hi, e
        assert abs(e["estimate"] - e["start"]) > 0.2 * e["start"]          # it moved: the start was wrong
    # the held-out n = 3 rows are predicted within their own scatter (3%, z of order 1)
    for output in ("v", "omega_h"):
        assert res["predict"]["summary"][output]["rms_z"] < 3, res["predict"]["summary"]
    assert (tmp_path / "d1" / "fitted.toml").is_file() and (tmp_path / "d1" / "fit.png").is_file()
