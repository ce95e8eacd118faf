"""``flagbot bench startup`` times a cold first run alone: the background compile that run leaves behind
(physics/warmup.py) is waited for before the next round's commands start (it ran beside them and made both
cold and warm look up to 1.7x slower)."""
import subprocess
import sys
import time

from flagbot_sim.bench.startup import wait_for_background_compile

HOLD = """
import fcntl, sys, time
f = open(sys.argv[1], "w")
fcntl.flock(f, fcntl.LOCK_EX)
print("locked", flush=True)
time.sleep(float(sys.argv[2]))
open(sys.argv[3], "w").close()          # the mark, then the release
fcntl.flock(f, fcntl.LOCK_UN)
time.sleep(30)
"""


def test_the_wait_ends_when_the_background_compile_releases_its_lock(tmp_path):
    lock = tmp_path / "index" / "flagbot_background.lock"      # somewhere inside the cache directory
    lock.parent.mkdir()
    mark = tmp_path / "released"
    p = subprocess.Popen([sys.executable, "-c", HOLD, str(lock), "1.5", str(mark)], stdout=subprocess.PIPE,
                         text=True)
    try:
        assert p.stdout.readline().strip() == "locked"
        wait_for_background_compile(tmp_path)
        assert mark.exists()             # it returned only once the holder had let go, not while it held the lock
    finally:
        p.kill()


def test_no_background_compile_means_no_wait_beyond_the_grace(tmp_path):
    t0 = time.monotonic()
    wait_for_background_compile(tmp_path, appear=0.2)
    assert time.monotonic() - t0 < 60          # returns (the bound only guards against a hang, not a speed)


def test_the_warm_start_breakdown_runs_and_names_every_phase():
    """`flagbot bench startup --breakdown` times a warm start phase by phase in a child process (it failed with an
    ImportError once the process's age moved from cli to cliutil, and nothing ran it)."""
    from flagbot_sim.bench.startup import _breakdown_process
    data, shutdown = _breakdown_process("design1", "fast")
    marks = data["marks"]
    for phase in ("numpy", "numba", "load_scene", "Simulation(): model set-up + kernel cache loads",
                  "10 steps (first calls of the step kernels)"):
        assert phase in marks and marks[phase] >= 0.0
    assert data["age"] > 0.0 and shutdown >= 0.0


def test_the_verdict_is_the_median_rounds_and_says_how_many_rounds_met_the_target():
    from flagbot_sim.bench.startup import target_verdict
    assert target_verdict([4.5, 5.6, 5.4], 5.0) == "target <= 5: misses it (met in 1 of 3 rounds)"
    assert target_verdict([1.9, 2.1, 1.95, 2.0, 1.5], 2.0) == "target <= 2: meets it (met in 4 of 5 rounds)"
