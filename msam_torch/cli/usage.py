"""The reference of the ``msam`` command line, generated from its parser
(:func:`~msam_torch.cli.main.build_parser`): ``python -m msam_torch.cli.usage`` prints it as
Markdown (the docs publish it as ``docs/reference/cli.md``, and a test holds the two equal), so no
option can be missing from it."""
from __future__ import annotations

import argparse

from msam_torch.cli.main import build_parser


def _commands(parser: argparse.ArgumentParser) -> dict[str, tuple[str, argparse.ArgumentParser]]:
    """name -> (one-line help, parser) of each sub-command."""
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {choice.dest: choice.help for choice in action._choices_actions}
    return {name: (helps.get(name, ""), sub) for name, sub in action.choices.items()}


def _row(action: argparse.Action) -> str:
    """One option or argument as a table row: flags (with the value it takes), default, meaning."""
    if action.option_strings:
        value = "" if action.nargs == 0 else f" {action.metavar or action.dest.upper()}"
        name = ", ".join(f"`{flag}{value}`" for flag in action.option_strings)
    else:
        name = f"`{action.dest.upper()}`" + (" ..." if action.nargs in ("*", "+") else "")
    default = "" if action.default in (None, False, argparse.SUPPRESS) or action.nargs == 0 else f"`{action.default}`"
    meaning = " ".join((action.help or "").split()).replace("|", "\\|")
    return f"| {name} | {default} | {meaning} |"


def markdown() -> str:
    """The reference page: every command with every argument and option."""
    parser = build_parser()
    lines = ["# Command line", "",
             ("Every command and option of `msam`, generated from its parser "
             "(`python -m msam_torch.cli.usage`). `msam` and `python -m msam_torch` are the same "
             "command. A wrong option or value ends in one line naming it and exit status 2; a "
             "record that tells nothing for a target, or a diagnosis or run that learnt nothing, ends with "
             "exit status 3."), ""]
    for name, (summary, sub) in _commands(parser).items():
        lines += [f"## `msam {name}`", "", f"{summary[:1].upper()}{summary[1:]}.", "",
                  f"```text\nmsam {name} CONFIG [OVERRIDES ...] [OPTIONS]\n```", "",
                  "| argument or option | default | meaning |", "|---|---|---|"]
        lines += [_row(a) for a in sub._actions if not isinstance(a, argparse._HelpAction)]
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown(), end="")
