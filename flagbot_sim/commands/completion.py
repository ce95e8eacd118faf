"""``flagbot completion bash|zsh``: the shell completion script (:mod:`flagbot_sim.completion`) of flagbot and the
ROS console scripts, generated from their parsers."""
from __future__ import annotations

import argparse
import functools
from typing import Callable


def register(sub, flagbot_parser: Callable[[], argparse.ArgumentParser]) -> None:
    """``flagbot completion``; ``flagbot_parser()`` builds the whole ``flagbot`` parser (every command module
    imported), which the script is generated from."""
    p = sub.add_parser(
        "completion", help="print a bash or zsh completion script for flagbot and the ROS console scripts",
        description="Print a static shell completion script for flagbot, sim_node, beam_node, cmd_profile, record "
                    "and replay, generated from their argument parsers (docs/cli.md). bash: write it to a file and "
                    "source that from ~/.bashrc; zsh: the same from ~/.zshrc, after compinit.")
    p.add_argument("shell", choices=("bash", "zsh"), help="the shell to complete in")
    p.set_defaults(func=functools.partial(cmd_completion, flagbot_parser=flagbot_parser))


def cmd_completion(args, flagbot_parser: Callable[[], argparse.ArgumentParser]) -> int:
    from ..completion import script
    print(script(args.shell, flagbot_parser()), end="")
    return 0
