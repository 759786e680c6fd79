"""Argument types of the ``torchtof`` command line: a bad value is refused by argparse, before
any work, with one line naming the option (``argument --n: expected an int >= 1, got '0'``).
"""

from __future__ import annotations

import argparse
import json

__all__ = ["positive_int", "nonneg_int", "sampling_rate", "positive_float", "json_object",
           "csv_list"]


def _int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def positive_int(text: str) -> int:
    """An integer ``>= 1``.

    Example:
        >>> positive_int("3")
        3
    """
    v = _int(text)
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return v


def nonneg_int(text: str) -> int:
    """An integer ``>= 0``."""
    v = _int(text)
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return v


def positive_float(text: str) -> float:
    """A finite number ``> 0``."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (v > 0 and v != float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return v


def sampling_rate(text: str) -> float:
    """A sampling rate ``M / n²`` in ``(0, 1]``.

    Example:
        >>> sampling_rate("0.125")
        0.125
    """
    v = positive_float(text)
    if v > 1:
        raise argparse.ArgumentTypeError(f"expected a sampling rate in (0, 1], got {text!r}")
    return v


def json_object(text: str) -> dict:
    """A JSON object (``'{"key": 1}'``)."""
    try:
        v = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r} ({exc.msg} at "
                                         f"character {exc.pos})") from None
    if not isinstance(v, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return v


def csv_list(choices):
    """A type: a comma-separated list of names from ``choices`` (case-insensitive), returned
    with the spelling of ``choices``.

    Example:
        >>> csv_list(["CGI", "TVAL3"])("cgi,TVAL3")
        ['CGI', 'TVAL3']
    """
    table = {c.lower(): c for c in choices}

    def parse(text: str) -> list[str]:
        names = [t.strip() for t in text.split(",") if t.strip()]
        bad = [t for t in names if t.lower() not in table]
        if not names or bad:
            raise argparse.ArgumentTypeError(
                f"expected a comma-separated subset of {', '.join(choices)}, got {text!r}")
        return [table[t.lower()] for t in names]

    parse.__name__ = "list"
    return parse
