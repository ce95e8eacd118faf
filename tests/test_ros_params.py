"""The node-side guards of flagbot_sim/values.py on their own (no node): the time limit on work done inside a
set-parameters callback, and the scene reader (scene.py's, shared with the CLI) that never blocks."""
import os
import threading
import time

import pytest

from flagbot_sim.scene import SceneError, load_scene
from flagbot_sim.scene_files import MAX_FILE_BYTES, read_scene_text
from flagbot_sim.values import TimeLimited, node_scene


def test_time_limited_work_is_refused_when_it_overruns_and_blocks_nothing_after():
    limited = TimeLimited(0.2, "the slow build")
    release = threading.Event()
    t0 = time.monotonic()
    with pytest.raises(SceneError, match="took longer than 0.2 s"):
        limited.run(lambda: release.wait(60))
    # the caller got its answer at the limit, not when the work ended (60 s later): a bound no load can reach
    assert time.monotonic() - t0 < 30.0 and not release.is_set()
    with pytest.raises(SceneError, match="still running"):
        limited.run(lambda: 1)                         # the overrunning work has not finished: refuse more
    release.set()
    time.sleep(0.1)
    assert limited.run(lambda: 42) == 42               # once it finished, work is accepted again
    with pytest.raises(ZeroDivisionError):             # the work's own errors reach the caller
        limited.run(lambda: 1 / 0)


def test_scene_reader_refuses_fifos_directories_and_big_or_binary_files_without_blocking(tmp_path):
    fifo = tmp_path / "s.toml"
    os.mkfifo(fifo)              # nobody writes: a blocking open or read would hang this test
    with pytest.raises(SceneError, match="FIFO"):
        read_scene_text(fifo)
    with pytest.raises(SceneError, match="directory"):
        read_scene_text(tmp_path)
    big = tmp_path / "big.toml"
    big.write_bytes(b"#" * (MAX_FILE_BYTES + 1))
    with pytest.raises(SceneError, match="larger than 1 MiB"):
        read_scene_text(big)
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b"[scene]\nname = \"caf\xe9\"\n")
    with pytest.raises(SceneError, match="not UTF-8 text .TOML must be.: byte 0xe9 at line 2, column 12"):
        read_scene_text(latin)
    ok = tmp_path / "ok.toml"
    ok.write_text("[robot]\nn_flagella = 3\n")
    assert read_scene_text(ok) == "[robot]\nn_flagella = 3\n"
    assert node_scene(str(ok), 0, []).robot.n_flagella == 3
    assert node_scene(str(ok), 4, ["flagellum.length=0.2"]).robot.n_flagella == 4


def test_the_nodes_refuse_an_empty_scene_file_as_the_cli_does(tmp_path):
    """An empty or comments-only scene file would run on every default without a word (`flagbot run` refuses it;
    sim_node and beam_node took it): one reading, shared by load_scene and the nodes, refuses it."""
    empty = tmp_path / "empty.toml"
    empty.write_text("# nothing here\n\n[robot]\n")
    with pytest.raises(SceneError) as err:
        node_scene(str(empty), 0, [])
    assert "sets no keys" in str(err.value)
    with pytest.raises(SceneError):
        load_scene(str(empty))


def test_beam_node_refuses_the_clamped_scene_as_flagbot_beam_does():
    """The beam balance is the free robot's: for the clamped flagellum beam_node published omega_h = omega_t =
    v = 0 (and `flagbot beam` refused it); both now use BeamParams.for_free_robot."""
    from flagbot_sim.beam import BeamParams
    with pytest.raises(SceneError) as err:
        BeamParams.for_free_robot(node_scene("clamped_flagellum", 0, []))
    assert "clamps its flagellum" in str(err.value)
    assert BeamParams.for_free_robot(node_scene("design1", 0, [])).n == 2


@pytest.mark.parametrize("scene, overrides, words", [
    ("", [], "built-in scene"),
    ("design1", ["scene.effects=[[1]]"], "scene.effects"),      # once a scene-check crash: now a refusal naming the key
    ("design1", ["x" * 100000], "at most 4096"),
    ("design1", ["medium.mu=1"] * 65, "at most 64"),
])
def test_node_scene_turns_every_failure_into_a_short_scene_error(scene, overrides, words):
    with pytest.raises(SceneError) as err:
        node_scene(scene, 0, overrides)
    assert words in str(err.value) and len(str(err.value)) <= 300 and "\n" not in str(err.value)
