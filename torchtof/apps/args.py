"""Argument types of the ``torchtof`` command line: a bad value is refused by argparse, before
any work, with one line naming the option (``argument --n: expected an int >= 1, got '0'``).
"""

from __future__ import annotations

import argparse
import json
import sys

__all__ = ["OneLineParser", "check_patterns", "positive_int", "nonneg_int", "power_of_two",
           "scene_side", "sampling_rate", "positive_float", "json_object", "csv_list", "scene"]


class OneLineParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose mistakes are one line (``PROG: error: argument --n: …``,
    exit status 2; the usage is printed too when :attr:`debug` is set) and whose options are
    never abbreviated (``--n`` must not silently mean ``--n-layers``)."""

    #: Print the usage block before the error line (``torchtof --debug``).
    debug = False

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        if OneLineParser.debug:
            self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error: {message} (`{self.prog} -h` lists the options)\n")


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


def power_of_two(text: str, lo: int | None = None) -> int:
    """A DMD side: a power of two in ``[4, 256]`` (the range of
    :class:`torchtof.operators.Hadamard`).

    Example:
        >>> power_of_two("64")
        64
    """
    from ..operators.patterns import N_MAX, N_MIN

    lo = N_MIN if lo is None else lo
    v = _int(text)
    if v < lo or v > N_MAX or v & (v - 1):
        raise argparse.ArgumentTypeError(
            f"expected a power of two in [{lo}, {N_MAX}], got {text!r}")
    return v


def scene_side(text: str) -> int:
    """The side of a simulated scene: a power of two in ``[8, 256]`` (the scenes of
    :func:`torchtof.scenes.get_scene` need ``n >= 8``)."""
    return power_of_two(text, lo=8)


def scene(text: str) -> str:
    """A scene name of :func:`torchtof.scenes.get_scene`: one of ``SCENES`` or
    ``skimage:<image>`` / ``binary:<image>``; a wrong name is answered with the valid ones.

    Example:
        >>> scene("skimage:camera")
        'skimage:camera'
    """
    from ..scenes import SCENES, SKIMAGE_NAMES

    prefix, _, image = text.partition(":")
    if text in SCENES or (prefix in ("skimage", "binary") and image in SKIMAGE_NAMES):
        return text
    if prefix in ("skimage", "binary") and _:
        raise argparse.ArgumentTypeError(
            f"unknown image {image!r} after '{prefix}:'; choose from {', '.join(SKIMAGE_NAMES)}")
    raise argparse.ArgumentTypeError(
        f"unknown scene {text!r}; choose from {', '.join(SCENES)}, skimage:<image>, "
        f"binary:<image> (<image>: {', '.join(SKIMAGE_NAMES)})")


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


def check_patterns(n: int, sr: float) -> None:
    """Cross-option check of ``--n`` and ``--sr``: the Hadamard rows exist (one line naming
    ``--sr`` otherwise)."""
    from ..operators import Hadamard

    try:
        Hadamard(n, sr=sr)
    except ValueError as exc:
        raise ValueError(f"argument --sr: with --n {n}: {str(exc).split(': ', 1)[-1]}") from None
