"""Argument types of the command line (:mod:`msam_torch.cli.main`): each parses one option's text or
raises the one-line usage error argparse prints with the option's name."""
from __future__ import annotations

import argparse

from msam_torch.errors import MSAMError


def solver(text: str) -> str:
    """An argparse type: a torchdiffeq method name, else a one-line usage error naming the option."""
    from msam_torch.diagnosis.compare.comparison import check_solver
    try:
        check_solver(text)
    except MSAMError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("solver: ")) from None
    return text


def positive(kind, zero: bool = False):
    """An argparse type: a finite positive ``kind`` (int or float; with ``zero``, 0 too), else a
    one-line usage error."""
    number = ("whole " if kind is int else "") + "number"
    wanted = f"a {number} of at least 0" if zero else f"a positive {number}"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            value = -1
        if not (0 <= value if zero else 0 < value) or not value < float("inf"):
            raise argparse.ArgumentTypeError(f"{text!r} is not {wanted}")
        return value
    return parse
