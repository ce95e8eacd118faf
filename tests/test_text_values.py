"""Every text value is validated as a value, and one scene reader serves the CLI and the nodes.

Control characters (a newline, a NUL, ...) in scene overrides, scene names and paths are refused with a message
naming the field: through the CLI (`--set`), the scene files' one-line strings, and sim_node's parameters. The
`record` parameter refuses a symbolic link whose target is missing (opening it would create the target). A scene
file that starts with a UTF-8 BOM runs the same under `flagbot run` and sim_node: both read it with scene.py's
read_scene_text (sim_node had its own reader, which refused it).
"""
import json
import os

import pytest

from flagbot_sim.fields import control_character
from flagbot_sim.scene import SceneError, load_scene
from flagbot_sim.values import node_scene, record_refusal, text_refusal

from cli_helpers import flagbot

# the case: the newline started a second TOML line of the value, which was dropped (n stayed 2)
NEWLINE_OVERRIDE = "motor.omega_rpm=1\nrobot.n_flagella=3"
CONTROLS = ["\n", "\r", "\t", "\0", "\x1b", "\x7f", "\x85", "\u2028", "\u2029"]


@pytest.mark.parametrize("c", CONTROLS, ids=[f"U+{ord(c):04X}" for c in CONTROLS])
def test_a_control_character_is_found_and_named(c):
    found = control_character(f"ab{c}cd")
    assert found is not None and found.endswith(f"(U+{ord(c):04X})")
    assert control_character(f"ab{c}cd", allowed=c) is None
    assert control_character("plain text, spaces, ümlauts and 1e-3") is None


def test_an_override_with_a_newline_is_refused_naming_its_key_not_cut_short():
    with pytest.raises(SceneError) as err:
        load_scene("design1", [NEWLINE_OVERRIDE])
    msg = str(err.value)
    assert "motor.omega_rpm" in msg and "a newline (U+000A)" in msg and "\n" not in msg
    for c in ("\0", "\r", "\x1b"):
        with pytest.raises(SceneError, match=f"U\\+{ord(c):04X}"):
            load_scene("design1", [f"motor.omega_rpm=1{c}"])
    # the same value on one line is accepted, and a TOML escape inside a quoted string is not a control character
    assert load_scene("design1", ["motor.omega_rpm=1"]).motor.omega_rpm == 1.0
    assert load_scene("design1", ['scene.description="two\\nlines"']).scene.description == "two\nlines"


@pytest.mark.parametrize("name", ["design1\n", "des\0ign1", "design1\r", "a\u2028b.toml"])
def test_a_scene_name_or_path_with_a_control_character_is_refused(name):
    with pytest.raises(SceneError) as err:
        load_scene(name)
    assert str(err.value).startswith("scene ") and "holds" in str(err.value)


@pytest.mark.parametrize("value", ['"a\\u0085b"', '"a\\u2028b"', '"a\\tb"', '"a\\u0000b"'])
def test_a_one_line_scene_string_refuses_every_control_character(value, tmp_path):
    """scene.name is one line of printable text (the node logs and the recordings' metadata carry it); the
    free-text scene.description may hold tabs and newlines, but not the other control characters."""
    f = tmp_path / "s.toml"
    f.write_text(f"[scene]\nname = {value}\n[robot]\nn_flagella = 2\n")
    with pytest.raises(SceneError, match="scene.name = .* holds"):
        load_scene(f)
    desc = tmp_path / "d.toml"
    desc.write_text(f"[scene]\ndescription = {value}\n[robot]\nn_flagella = 2\n")
    if value == '"a\\tb"':
        assert load_scene(desc).scene.description == "a\tb"
    else:
        with pytest.raises(SceneError, match="scene.description = .* holds"):
            load_scene(desc)


def test_node_values_are_refused_naming_the_parameter():
    with pytest.raises(SceneError) as err:
        node_scene("design1", 0, [NEWLINE_OVERRIDE])
    assert "scene_overrides" in str(err.value) and "U+000A" in str(err.value)
    with pytest.raises(SceneError) as err:
        node_scene("design1\n", 0, [])
    assert str(err.value).startswith("scene = ") and "U+000A" in str(err.value)
    assert "foxglove_host" in text_refusal("foxglove_host", "127.0.0.1\n")
    assert text_refusal("foxglove_host", "127.0.0.1") is None


def test_record_refuses_control_characters_and_a_dangling_symbolic_link(tmp_path):
    for bad in ("run\n.mcap", "run\0x.mcap", "ru\rn.mcap"):
        reason = record_refusal(str(tmp_path / bad))
        assert reason is not None and reason.startswith("record = ") and "holds" in reason
    target = tmp_path / "elsewhere" / "target.mcap"
    target.parent.mkdir()
    link = tmp_path / "link.mcap"
    link.symlink_to(target)
    reason = record_refusal(str(link))
    assert reason is not None and "symbolic link" in reason and "does not exist" in reason
    # the writer appends .mcap to a name without it: a dangling link there is refused too
    (tmp_path / "run.mcap").symlink_to(target)
    assert "symbolic link" in record_refusal(str(tmp_path / "run"))
    # a link to a file that exists is left to the writer (which refuses an existing file); a plain new name passes
    target.write_bytes(b"x")
    assert record_refusal(str(link)) is None
    assert record_refusal(str(tmp_path / "new.mcap")) is None and record_refusal("") is None
    assert not (tmp_path / "new.mcap").exists()


def test_rclpy_ends_a_string_at_its_first_nul():
    """Why a NUL in a parameter cannot be refused by the node (msg_docs/sim_node.md): rclpy's serialisation sends
    the string up to its first NUL, and its deserialisation of a longer one stops there too."""
    import struct

    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import String
    assert deserialize_message(serialize_message(String(data="a\0b")), String).data == "a"
    whole = b"\x00\x01\x00\x00" + struct.pack("<I", 4) + b"a\0b\0"      # CDR of the 3-character string
    assert deserialize_message(whole, String).data == "a"


def bom_scene(tmp_path):
    """design2 with n = 3, its file starting with a UTF-8 byte order mark (some Windows editors write one)."""
    from flagbot_sim.scene_files import resolve_scene_path
    text = resolve_scene_path("design2").read_text().replace("n_flagella = 2", "n_flagella = 3")
    assert "n_flagella = 3" in text
    f = tmp_path / "bom_design2.toml"
    f.write_bytes(b"\xef\xbb\xbf" + text.encode())
    return f


def test_a_scene_file_with_a_bom_reads_the_same_for_the_cli_and_the_nodes(tmp_path):
    f = bom_scene(tmp_path)
    cli, node = load_scene(f), node_scene(str(f), 0, [])
    assert cli.to_dict() == node.to_dict() and node.robot.n_flagella == 3
    assert cli.to_dict() == load_scene("design2", ["robot.n_flagella=3", f"scene.name='{f.stem}'"]).to_dict()


def test_the_standalone_recorder_stores_a_bom_scene_as_readable_toml(tmp_path):
    """`record --scene FILE` stores the scene's text in the recording: read by the same reader, without the BOM
    that tomllib (and so --resimulate) would refuse."""
    import tomllib

    from flagbot_sim.ros.recorder import scene_text
    text = scene_text(str(bom_scene(tmp_path)))
    assert not text.startswith("\ufeff") and tomllib.loads(text)["robot"]["n_flagella"] == 3


def test_the_cli_runs_a_bom_scene_and_refuses_a_newline_override(tmp_path):
    f = bom_scene(tmp_path)
    r = flagbot("run", str(f), "--duration", "0.02", "--set", "flagellum.length=0.03", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["n_flagella"] == 3
    r = flagbot("run", "design1", "--duration", "0.02", "--set", NEWLINE_OVERRIDE)
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "motor.omega_rpm" in lines[0]
    assert "U+000A" in lines[0] and "Traceback" not in r.stderr


def test_sim_node_runs_a_bom_scene_and_refuses_control_characters_and_dangling_links(ros, tmp_path):
    from ros_helpers import DISCOVERY_TIMEOUT, NodeProcess, get_params, set_params, spin_until
    f = bom_scene(tmp_path)
    target = tmp_path / "elsewhere.mcap"
    link = tmp_path / "link.mcap"
    link.symlink_to(target)
    proc = NodeProcess("flagbot_sim.ros.sim_node", "--ros-args", "-p", f"scene:={f}", "-p", "start_paused:=true",
                       "-p", 'scene_overrides:=["flagellum.length=0.03"]')
    try:
        spin_until(ros, lambda: "sim_node" in ros.get_node_names(), DISCOVERY_TIMEOUT, "sim_node")
        assert get_params(ros, "sim_node", ["scene"])["scene"] == str(f)
        refused = {
            "scene_overrides": (["flagellum.length=0.03", NEWLINE_OVERRIDE], "U+000A"),
            "scene": ("design1\n", "U+000A"),
            "record": (str(tmp_path / "run\n.mcap"), "U+000A"),
            "foxglove_host": ("127.0.0.1\r", "U+000D"),
        }
        for name, (value, words) in refused.items():
            (res,) = set_params(ros, "sim_node", **{name: value})
            assert not res.successful and name in res.reason and words in res.reason, (name, res.reason)
            print(name, "->", res.reason)
        (res,) = set_params(ros, "sim_node", record=str(link))
        assert not res.successful and "symbolic link" in res.reason
        assert not target.exists() and not os.path.exists(tmp_path / "run\n.mcap")
        # the refused sets left everything as it was; the BOM scene is accepted at run time too
        assert get_params(ros, "sim_node", ["scene", "record"]) == {"scene": str(f), "record": ""}
        # a NUL never reaches the node (rclpy sends the string up to it): the node records to that part, and
        # says so in the parameter's value (msg_docs/sim_node.md, `record`)
        (res,) = set_params(ros, "sim_node", record=str(tmp_path / "cut\0off.mcap"))
        assert res.successful, res.reason
        assert get_params(ros, "sim_node", ["record"])["record"] == str(tmp_path / "cut")
        (res,) = set_params(ros, "sim_node", record="")
        assert res.successful and (tmp_path / "cut.mcap").is_file() and not list(tmp_path.glob("*off*"))
        (res,) = set_params(ros, "sim_node", scene="design1")
        assert res.successful, res.reason
        (res,) = set_params(ros, "sim_node", scene=str(f))
        assert res.successful, res.reason
    finally:
        code, log = proc.stop()
    assert code == 0 and "Traceback" not in log, log
    assert f"scene {f.stem}, n = 3" in log           # the start-up line: the BOM file's n_flagella = 3
