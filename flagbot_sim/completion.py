"""``flagbot completion bash|zsh``: a static shell completion script generated from the argparse parsers.

One script completes every console script of the package: ``flagbot`` (its commands, nested ones such as
``flagbot bench accuracy``, every option, the choices of an option or positional, built-in scene names, the
``section.key=`` of ``--set``, file names), ``cmd_profile``, ``record`` and ``replay`` (their own parsers), and
``sim_node`` / ``beam_node`` (``--help``, ``--version`` and the ``--ros-args`` words; their parameters are ROS
parameters, listed by ``--help``).

Why generated here rather than by a dependency: argcomplete runs the Python program at every TAB (for ``flagbot``
that is an interpreter start, twice with the ROS 2 wheels' re-exec: ``flagbot --version`` takes 1.0-1.3 s on the
shared 2-core development host). shtab writes static scripts from the argparse tree too, but it would be one more
install requirement for what this module does, and the scene names and ``--set`` keys would still have to be
added to it by hand. The zsh script is the bash one run through zsh's own ``bashcompinit`` emulation, so both
shells share one completion logic (``tests/test_completion.py`` runs it in bash, and in zsh where installed).

The script holds the tree as it was when generated: regenerate it after an upgrade (docs/cli.md).
"""
from __future__ import annotations

import argparse
import shlex
from dataclasses import dataclass, field

from . import __version__

SHELLS = ("bash", "zsh")

#: the console scripts completed, in the order of setup.py's EXECUTABLES
PROGRAMS = ("flagbot", "sim_node", "beam_node", "cmd_profile", "record", "replay")
#: the programs that take a ``--ros-args ... [--]`` section
ROS_PROGRAMS = ("sim_node", "beam_node", "cmd_profile", "record", "replay")
#: the words offered inside ``--ros-args`` (rcl's arguments), and what the value after each is
ROS_ARGS = {"-p": "none", "--param": "none", "-r": "none", "--remap": "none", "--params-file": "file",
            "-e": "none", "--enclave": "none", "--log-level": "debug info warn error fatal", "--": None}


@dataclass
class Node:
    """One parser of the tree (a program or a subcommand): what can follow it on the command line."""
    options: list = field(default_factory=list)       # every option string
    values: dict = field(default_factory=dict)        # option that takes a value -> what the value completes to
    commands: dict = field(default_factory=dict)      # subcommand -> Node
    positionals: list = field(default_factory=list)   # what each positional completes to


#: what the value of an argument completes to, by the argument's name (argparse ``dest``): one table for every
#: command, since the commands name their arguments alike. An argument with choices completes to them; any other
#: argument (a number, a list, a topic, a host) to nothing.
KINDS = {"scene": "scene", "sources": "scene",          # a built-in scene name, or a scene / recording file
         "overrides": "scene_key",                      # --set section.key=
         **dict.fromkeys(("out", "output", "record", "plot", "gif", "data", "predict", "bag", "dir", "plot_from"),
                         "file")}


def _kind(action: argparse.Action):
    """What a value of ``action`` completes to: a list of words, or "scene", "scene_key", "file", "none"."""
    if action.choices is not None:
        return [str(c) for c in action.choices]
    return KINDS.get(action.dest, "none")


def tree(parser: argparse.ArgumentParser) -> Node:
    """The completion tree of ``parser`` and its subparsers (argparse's own records of them)."""
    node = Node()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                node.commands[name] = tree(sub)
        elif action.option_strings:
            node.options += action.option_strings
            if action.nargs != 0:
                for opt in action.option_strings:
                    node.values[opt] = _kind(action)
        elif action.nargs != 0:
            node.positionals.append(_kind(action))
    return node


def ros_node_tree() -> Node:
    """sim_node / beam_node: no argparse, only ``-h``, ``--version`` and the ROS arguments."""
    return Node(options=["-h", "--help", "--version", "--ros-args"])


def trees(flagbot: argparse.ArgumentParser) -> dict[str, Node]:
    """Every program's tree, from the parsers the programs themselves use (``flagbot``'s whole parser is given by
    flagbot_sim.cli, which this module does not import back)."""
    from .ros.bag_args import add_profile_arguments, add_record_arguments, add_replay_arguments, script_parser
    return {"flagbot": tree(flagbot),
            "sim_node": ros_node_tree(), "beam_node": ros_node_tree(),
            "cmd_profile": tree(script_parser("cmd_profile", "", add_profile_arguments)),
            "record": tree(script_parser("record", "", add_record_arguments)),
            "replay": tree(script_parser("replay", "", add_replay_arguments))}


def scene_words() -> tuple[list[str], list[str]]:
    """The built-in scene names and every ``section.key=`` a ``--set`` accepts."""
    import dataclasses

    from .scene import SECTIONS
    from .scene_files import builtin_scenes
    keys = [f"{s}.{f.name}=" for s, cls in SECTIONS.items() for f in dataclasses.fields(cls)]
    return builtin_scenes(), keys


# ------------------------------------------------------------------------------------------------ bash
def _q(words) -> str:
    """Words as one single-quoted shell word (each word is a plain token: option, name, key)."""
    return shlex.quote(" ".join(words))


def _walk(prefix: str, node: Node):
    """(path, node) of ``node`` and every subcommand below it, depth first."""
    yield prefix, node
    for name, sub in node.commands.items():
        yield from _walk(f"{prefix} {name}", sub)


def _value_flags(kind) -> tuple[list[str], str]:
    """(words, what else) of a value kind: the words to offer and "file", "scene", "key" or "" for nothing else."""
    if isinstance(kind, list):
        return kind, ""
    return [], {"scene": "scene", "scene_key": "key", "file": "file"}.get(kind, "")


def bash_script(programs: dict[str, Node]) -> str:
    """The bash completion script for ``programs`` (:func:`trees`: every console script of the package)."""
    scenes, keys = scene_words()
    node_cases, value_cases = [], []
    for prog, root in programs.items():
        for path, node in _walk(prog, root):
            pos_words, pos_more = [], set()
            for kind in node.positionals:
                w, more = _value_flags(kind)
                pos_words += w
                pos_more.add(more)
            more = "scene" if "scene" in pos_more else ("file" if "file" in pos_more else "")
            node_cases.append(f"        {shlex.quote(path)}) opts={_q(node.options)}; valopts={_q(node.values)}; "
                              f"cmds={_q(node.commands)}; pos={_q(pos_words)}; posmore={more};;")
            for opt, kind in node.values.items():
                w, more = _value_flags(kind)
                if w or more:
                    value_cases.append(f"        {shlex.quote(path + '|' + opt)}) words={_q(w)}; more={more};;")
    for opt, what in ROS_ARGS.items():
        if what not in (None, "none"):
            w, more = ([], "file") if what == "file" else (what.split(), "")
            value_cases.append(f"        {shlex.quote('ros|' + opt)}) words={_q(w)}; more={more};;")
    ros_words = [w for w in ROS_ARGS]
    ros_valopts = [w for w, what in ROS_ARGS.items() if what is not None]
    names = " ".join(programs)
    node_text, value_text = "\n".join(node_cases), "\n".join(value_cases)
    ros_progs = "|".join(p for p in programs if p in ROS_PROGRAMS) or "__none__"
    return f"""# Shell completion for flagbot_sim {__version__}: {names}.
# Generated by `flagbot completion bash` from the programs' own argument parsers; regenerate after an upgrade.
# Use: source it from ~/.bashrc, or write it to ~/.local/share/bash-completion/completions/flagbot (docs/cli.md).

# _flagbot_node PATH: what may follow the (sub)command PATH: its options, the options that take a value, its
# subcommands, the words of its positionals and whether a positional may be a scene or a file
_flagbot_node() {{
    opts=''; valopts=''; cmds=''; pos=''; posmore=''
    case $1 in
{node_text}
        *) return 1;;
    esac
}}

# _flagbot_value PATH OPTION: the words the value of OPTION completes to, and whether it may be a scene or a file
# (more=scene|key|file)
_flagbot_value() {{
    words=''; more=''
    case "$1|$2" in
{value_text}
        *) return 1;;
    esac
}}

_flagbot_in() {{  # WORD LIST: whether WORD is one of the words of LIST
    local w
    for w in $2; do [[ $w == "$1" ]] && return 0; done
    return 1
}}

_flagbot_offer() {{  # CURRENT WORDS MORE: fill COMPREPLY
    local cur=$1 w
    COMPREPLY=($(compgen -W "$2" -- "$cur"))
    case $3 in
        scene) COMPREPLY+=($(compgen -W {_q(scenes)} -- "$cur"));;
        key) COMPREPLY+=($(compgen -W {_q(keys)} -- "$cur"))
             type compopt >/dev/null 2>&1 && compopt -o nospace 2>/dev/null;;
    esac
    case $3 in
        scene|file)       # one file name a line: names with spaces stay whole
            while IFS= read -r w; do COMPREPLY+=("$w"); done < <(compgen -f -- "$cur")
            type compopt >/dev/null 2>&1 && compopt -o filenames 2>/dev/null;;
    esac
}}

_flagbot_complete() {{
    local cur=${{COMP_WORDS[COMP_CWORD]}} prev='' prog=${{COMP_WORDS[0]##*/}} path i w skip=0 ros=0 eq=
    local opts valopts cmds pos posmore words more
    (( COMP_CWORD > 0 )) && prev=${{COMP_WORDS[COMP_CWORD-1]}}
    COMPREPLY=()
    path=$prog
    _flagbot_node "$path" || return 0
    # the words before the cursor: follow the subcommands, step over option values and --ros-args sections
    for (( i = 1; i < COMP_CWORD; i++ )); do
        w=${{COMP_WORDS[i]}}
        if (( skip )); then [[ $w == = ]] || skip=0; continue; fi
        if (( ros )); then
            if [[ $w == -- ]]; then ros=0; elif _flagbot_in "$w" {_q(ros_valopts)}; then skip=1; fi
            continue
        fi
        case $w in
            --ros-args) case $prog in {ros_progs}) ros=1;; esac;;
            =) skip=1;;
            -*=*) ;;
            -*) _flagbot_in "$w" "$valopts" && skip=1;;
            *) if _flagbot_in "$w" "$cmds"; then path="$path $w"; _flagbot_node "$path"; fi;;
        esac
    done
    # the value of an option: --opt VALUE, or --opt=VALUE, which bash splits into three words at the '=' and zsh
    # keeps as one (its completions then carry the '--opt=' in front)
    if [[ $cur == = ]]; then cur=''; skip=1
    elif [[ $prev == = ]] && (( COMP_CWORD > 1 )); then prev=${{COMP_WORDS[COMP_CWORD-2]}}; skip=1
    elif [[ $cur == -*=* ]]; then eq=${{cur%%=*}}=; prev=${{cur%%=*}}; cur=${{cur#*=}}; skip=1
    fi
    if (( skip )); then
        if (( ros )); then _flagbot_value ros "$prev" || return 0
        else _flagbot_value "$path" "$prev" || return 0
        fi
        _flagbot_offer "$cur" "$words" "$more"
        [[ -n $eq ]] && COMPREPLY=("${{COMPREPLY[@]/#/$eq}}")
        return 0
    fi
    if (( ros )); then
        _flagbot_offer "$cur" {_q(ros_words)} ""
    elif [[ $cur == -* ]]; then
        _flagbot_offer "$cur" "$opts" ""
    else
        _flagbot_offer "$cur" "$cmds $pos" "$posmore"
    fi
    return 0
}}

complete -F _flagbot_complete {names}
"""


def zsh_script(programs: dict[str, Node]) -> str:
    """The zsh completion script: the bash one under zsh's ``bashcompinit`` (one completion logic)."""
    return ("# zsh: the bash completion below, run through zsh's own bash emulation (bashcompinit).\n"
            "# Use: source it from ~/.zshrc after compinit (docs/cli.md).\n"
            "autoload -U +X bashcompinit && bashcompinit\n" + bash_script(programs))


def script(shell: str, flagbot: argparse.ArgumentParser) -> str:
    """``flagbot completion SHELL``: the script for every console script, ``flagbot``'s tree from its parser."""
    if shell not in SHELLS:
        raise ValueError(f"shell must be one of {', '.join(SHELLS)}, got {shell!r}")
    return (bash_script if shell == "bash" else zsh_script)(trees(flagbot))
