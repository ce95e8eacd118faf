"""``flagbot completion bash|zsh``: the generated script is valid shell and completes what the parsers accept.

bash: the script is sourced and its completion function called the way bash's programmable completion calls it
(COMP_WORDS / COMP_CWORD set, COMPREPLY read back). zsh (where installed): a real interactive zsh in a pseudo
terminal (zsh's own zpty module) loads it and the test presses TAB.
"""
import shutil
import subprocess
from pathlib import Path

import pytest

from flagbot_sim import cli, completion
from flagbot_sim.ros.bag_args import add_replay_arguments, script_parser
from cli_helpers import flagbot


@pytest.fixture(scope="module")
def bash_script(tmp_path_factory):
    p = flagbot("completion", "bash")
    assert p.returncode == 0, p.stderr
    path = tmp_path_factory.mktemp("completion") / "flagbot.bash"
    path.write_text(p.stdout)
    return path


def complete(script: Path, *words: str, cwd=None) -> list[str]:
    """What bash offers for the command line ``words`` (the last is the word being completed)."""
    line = " ".join(f"'{w}'" for w in words)
    program = (f"source '{script}'\nCOMP_WORDS=({line}); COMP_CWORD={len(words) - 1}; COMPREPLY=()\n"
               "_flagbot_complete\nprintf '%s\\n' \"${COMPREPLY[@]}\"\n")
    p = subprocess.run(["bash", "--norc", "--noprofile", "-c", program], capture_output=True, text=True,
                       timeout=30, cwd=cwd)
    assert p.returncode == 0 and p.stderr == "", p.stderr
    return [w for w in p.stdout.splitlines() if w]


def test_the_bash_script_is_valid_bash_and_registers_every_console_script(bash_script):
    p = subprocess.run(["bash", "-n", str(bash_script)], capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    p = subprocess.run(["bash", "--norc", "-c", f"source '{bash_script}'; complete -p"], capture_output=True,
                       text=True)
    registered = {line.split()[-1] for line in p.stdout.splitlines() if "-F _flagbot_complete" in line}
    assert registered == set(completion.PROGRAMS)


def test_bash_completes_subcommands_nested_ones_and_options(bash_script):
    # the commands are exactly the parser's (build_parser("*") registers every module's)
    parser = cli.build_parser("*")
    commands = set(parser._subparsers._group_actions[0].choices)
    assert set(complete(bash_script, "flagbot", "")) == commands and "completion" in commands
    assert complete(bash_script, "flagbot", "be") == ["beam", "bench"]
    assert complete(bash_script, "flagbot", "bench", "") == ["accuracy", "speed", "memory", "startup", "flood",
                                                                 "steady"]
    assert complete(bash_script, "flagbot", "--v") == ["--version"]
    assert complete(bash_script, "flagbot", "sweep", "design2", "--eng") == ["--engine"]
    assert complete(bash_script, "flagbot", "bench", "accuracy", "--qu") == ["--quick"]
    # the options of a subcommand are its own (sweep's --grid is not offered after run)
    assert complete(bash_script, "flagbot", "run", "design2", "--gr") == []


def test_bash_completes_values_choices_scenes_keys_and_files(bash_script, tmp_path):
    assert complete(bash_script, "flagbot", "beam", "design2", "--regime", "nlb") == ["nlb-nohead", "nlb"]
    # --opt=VALUE: bash splits the word at '='
    assert complete(bash_script, "flagbot", "beam", "--regime", "=", "l") == ["lb"]
    assert complete(bash_script, "flagbot", "run", "des") == ["design1", "design2"]
    assert complete(bash_script, "flagbot", "run", "design2", "--set", "motor.om") == ["motor.omega_rpm="]
    # a number completes to nothing (no file names after --duration); an option's value is skipped over
    assert complete(bash_script, "flagbot", "run", "design2", "--duration", "") == []
    assert complete(bash_script, "flagbot", "run", "--duration", "5", "--js") == ["--json"]
    (tmp_path / "my scene.toml").write_text("")
    (tmp_path / "other.mcap").write_text("")
    assert complete(bash_script, "flagbot", "run", "my", cwd=tmp_path) == ["my scene.toml"]   # one word
    assert complete(bash_script, "flagbot", "bag-summary", "o", cwd=tmp_path) == ["other.mcap"]
    assert complete(bash_script, "flagbot", "completion", "") == ["bash", "zsh"]


def test_bash_completes_the_ros_console_scripts(bash_script):
    assert complete(bash_script, "sim_node", "--") == ["--help", "--version", "--ros-args"]
    assert "-p" in complete(bash_script, "sim_node", "--ros-args", "-")
    assert complete(bash_script, "beam_node", "--ros-args", "--log-level", "w") == ["warn"]
    # after the section's '--' the program's own options again
    assert complete(bash_script, "sim_node", "--ros-args", "-p", "a:=1", "--", "--v") == ["--version"]
    assert complete(bash_script, "cmd_profile", "s") == ["steps", "square"]
    assert "--resimulate" in complete(bash_script, "replay", "--re")
    # a path with directories before the program's name
    assert complete(bash_script, "/opt/venv/bin/record", "--comp") == ["--compression"]


def test_the_tree_is_the_parsers_own():
    """What the script offers comes from argparse: every option string of replay's parser, its choices."""
    parser = script_parser("replay", "", add_replay_arguments)
    node = completion.tree(parser)
    want = {s for a in parser._actions for s in a.option_strings}
    assert set(node.options) == want and "--version" in want
    beam = completion.tree(cli.build_parser("*")).commands["beam"]
    action = next(a for a in cli.build_parser("beam")._subparsers._group_actions[0].choices["beam"]._actions
                  if a.dest == "regime")
    assert beam.values["--regime"] == list(action.choices)
    shells = completion.tree(cli.build_parser("completion")).commands["completion"].positionals
    assert shells == [list(completion.SHELLS)]


@pytest.mark.skipif(shutil.which("zsh") is None, reason="zsh is not installed")
def test_zsh_completes_a_subcommand_and_an_option_on_tab(tmp_path):
    p = flagbot("completion", "zsh")
    assert p.returncode == 0, p.stderr
    script = tmp_path / "flagbot.zsh"
    script.write_text(p.stdout)
    assert subprocess.run(["zsh", "-n", str(script)], capture_output=True).returncode == 0
    # an interactive zsh in a pseudo terminal: type partial words and TAB, then make the line print itself
    # (Ctrl-A, "echo LINE=", Enter) to read what the TABs made of it. Each step waits for the terminal to show
    # its effect (zpty -r with a pattern), not for a time; a step that never shows ends in the timeout.
    driver = tmp_path / "drive.zsh"
    driver.write_text(f"""zmodload zsh/zpty
zpty z 'zsh -f -i'
zpty -w z 'PS1="%% "; autoload -U compinit; compinit -u -D; source {script}; echo READY'
zpty -r z line '*READY*'
zpty -w -n z $'flagbot ben\\t'
zpty -r z line '*bench*'
zpty -w -n z $'accuracy --qu\\t'
zpty -r z line '*quick*'
zpty -w z $'\\x01echo LINE='
zpty -r z line '*LINE=flagbot*'$'\\n'
print -r -- "$line"
zpty -d z
""")
    r = subprocess.run(["zsh", "-f", str(driver)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    lines = [ln.strip() for ln in r.stdout.replace("\r", "\n").splitlines() if ln.strip().startswith("LINE=")]
    # TAB turned "ben" into "bench" (the one command that starts so) and "--qu" into accuracy's "--quick"
    assert lines == ["LINE=flagbot bench accuracy --quick"], r.stdout[-800:]
