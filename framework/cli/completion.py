"""Shell completion scripts for ``spherecal``, written from its argparse parser (so a new
option completes without editing a script): ``spherecal completion bash`` and
``spherecal completion zsh`` print them (docs/cli.md, "Shell completion").

What completes: the commands; each command's options; the values of options with a
fixed set of choices (``--pose-from reported|joints``...); folders after ``-o/--out``;
file names for positional arguments and for options naming a file. Options that take a
number complete nothing.
"""

from __future__ import annotations

import argparse
import re

from spherecal.app.plugins import host_and_frame_options
from spherecal.cli.output import EXIT_OK
from spherecal.cli.parser import build_parser
from spherecal.cli.session import Session

#: Options whose value is a folder, and ones whose value is a file (by ``dest``).
FOLDER_DESTS = {"out"}
FILE_DESTS = {"config", "robot_config", "transform", "dataset", "a", "b"}


def _commands(parser: argparse.ArgumentParser) -> dict[str, tuple[argparse.ArgumentParser, str]]:
    """name -> (its parser, its one-line help), in the order they were added."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            return {name: (sub, helps.get(name, "")) for name, sub in action.choices.items()}
    return {}


def _options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions if a.option_strings]


def _positionals(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [a for a in parser._actions if not a.option_strings and not isinstance(a, argparse._SubParsersAction)]


def _takes_value(action: argparse.Action) -> bool:
    return action.nargs != 0


def run(args, session: Session) -> int:
    """``spherecal completion SHELL``: the script for the command line with the installed
    robot types' options."""
    _host, frame_options = host_and_frame_options()
    session.say(completion_script(build_parser(frame_options), args.shell))
    return EXIT_OK


def completion_script(parser: argparse.ArgumentParser, shell: str) -> str:
    """The completion script of ``parser`` (``spherecal``'s) for ``shell``: bash or zsh."""
    if shell == "bash":
        return bash_script(parser)
    if shell == "zsh":
        return zsh_script(parser)
    raise ValueError(f"shell: expected bash or zsh, got {shell!r}")


def bash_script(parser: argparse.ArgumentParser) -> str:
    prog = parser.prog
    fn = "_" + re.sub(r"\W", "_", prog)
    commands = _commands(parser)
    top = " ".join(o for a in _options(parser) for o in a.option_strings)
    value_cases, option_cases, positional_cases = [], [], []
    for name, (sub, _help) in commands.items():
        opts = [a for a in _options(sub)]
        option_cases.append(f'        {name}) opts="{" ".join(o for a in opts for o in a.option_strings)}" ;;')
        for a in opts:
            if not _takes_value(a):
                continue
            pattern = "|".join(f"{name}:{o}" for o in a.option_strings)
            if a.choices:
                value_cases.append(f'        {pattern}) COMPREPLY=($(compgen -W "{" ".join(map(str, a.choices))}" '
                                   '-- "$cur")); return 0 ;;')
            elif a.dest in FOLDER_DESTS:
                value_cases.append(f'        {pattern}) COMPREPLY=($(compgen -d -- "$cur")); return 0 ;;')
            elif a.dest in FILE_DESTS:
                value_cases.append(f'        {pattern}) COMPREPLY=($(compgen -f -- "$cur")); return 0 ;;')
            else:
                value_cases.append(f"        {pattern}) COMPREPLY=(); return 0 ;;")
        for a in _positionals(sub):
            if a.choices:
                positional_cases.append(f'        {name}) COMPREPLY=($(compgen -W "{" ".join(map(str, a.choices))}" '
                                        '-- "$cur")); return 0 ;;')
                break
    names = " ".join(commands)
    return f"""# bash completion for {prog}, written by `{prog} completion bash`.
# Load it with: source <({prog} completion bash)
# or save it as ~/.local/share/bash-completion/completions/{prog}
{fn}() {{
    local cur prev cmd i opts
    cur="${{COMP_WORDS[COMP_CWORD]}}"
    prev="${{COMP_WORDS[COMP_CWORD-1]}}"
    cmd=""
    for ((i = 1; i < COMP_CWORD; i++)); do
        case "${{COMP_WORDS[i]}}" in
            {"|".join(commands)}) cmd="${{COMP_WORDS[i]}}"; break ;;
        esac
    done
    if [[ -z "$cmd" ]]; then
        if [[ "$cur" == -* ]]; then
            COMPREPLY=($(compgen -W "{top}" -- "$cur"))
        else
            COMPREPLY=($(compgen -W "{names}" -- "$cur"))
        fi
        return 0
    fi
    case "$cmd:$prev" in
{chr(10).join(value_cases)}
    esac
    opts=""
    case "$cmd" in
{chr(10).join(option_cases)}
    esac
    if [[ "$cur" == -* ]]; then
        COMPREPLY=($(compgen -W "$opts" -- "$cur"))
        return 0
    fi
    case "$cmd" in
{chr(10).join(positional_cases) or "        '') ;;"}
    esac
    COMPREPLY=($(compgen -f -- "$cur"))
}}
complete -o filenames -o bashdefault -F {fn} {prog}
"""


def _zsh_text(text: str | None, limit: int = 70) -> str:
    """A help text made safe inside a zsh ``_arguments`` spec and a single-quoted word."""
    text = re.sub(r"\s*\([^)]*\)", "", (text or "").split(". ")[0])
    text = re.sub(r"[\[\]]", "", text).replace(":", " -").replace("'", "").replace("\\", "")
    text = re.sub(r"\s+", " ", text).strip()
    return text if len(text) <= limit else text[: limit - 3].rstrip() + "..."


def _zsh_action(a: argparse.Action) -> str:
    if a.choices:
        return f"({' '.join(map(str, a.choices))})"
    if a.dest in FOLDER_DESTS:
        return "_files -/"
    if a.dest in FILE_DESTS:
        return "_files"
    return " "


def _zsh_specs(parser: argparse.ArgumentParser) -> list[str]:
    specs = []
    for a in _options(parser):
        desc = _zsh_text(a.help)
        many = "*" if isinstance(a, argparse._CountAction) else ""
        for o in a.option_strings:
            if _takes_value(a):
                meta = (a.metavar or a.dest).lower() if isinstance(a.metavar or a.dest, str) else "value"
                specs.append(f"'{many}{o}[{desc}]:{_zsh_text(meta)}:{_zsh_action(a)}'")
            else:
                specs.append(f"'{many}{o}[{desc}]'")
    for i, a in enumerate(_positionals(parser), start=1):
        optional = ":" if a.nargs == "?" else ""
        specs.append(f"'{optional}{i}:{_zsh_text(a.metavar or a.dest)}:{_zsh_action(a)}'")
    return specs


def zsh_script(parser: argparse.ArgumentParser) -> str:
    prog = parser.prog
    fn = "_" + re.sub(r"\W", "_", prog)
    commands = _commands(parser)
    described = "\n".join(f"        '{name}:{_zsh_text(help_)}'" for name, (_s, help_) in commands.items())
    top = " \\\n        ".join(_zsh_specs(parser))
    cases = []
    for name, (sub, _h) in commands.items():
        specs = " \\\n                ".join(_zsh_specs(sub))
        cases.append(f"            {name})\n                _arguments {specs}\n                ;;")
    return f"""#compdef {prog}
# zsh completion for {prog}, written by `{prog} completion zsh`.
# Save it as _{prog} in a folder of $fpath (e.g. ~/.zfunc, with fpath+=(~/.zfunc) before compinit).
{fn}() {{
    local curcontext="$curcontext" state line
    local -a commands
    commands=(
{described}
    )
    _arguments -C \\
        {top} \\
        '1:command:->command' \\
        '*::argument:->argument'
    case $state in
        command)
            _describe -t commands '{prog} command' commands
            ;;
        argument)
            case $words[1] in
{chr(10).join(cases)}
            esac
            ;;
    esac
}}
{fn} "$@"
"""
