"""Memory estimates checked before a large allocation.

Entry points that could allocate more than the machine holds estimate their peak size first
and call :func:`check_memory`, which raises ``ValueError`` with the estimate and the limit
instead of letting the allocator fail (or the machine swap) half-way through.

The limit is, in this order: the value given to :func:`set_memory_limit`; the environment
variable ``TORCHTOF_MEMORY_LIMIT`` (bytes, or a number with a ``K``/``M``/``G``/``T``
suffix in binary units, e.g. ``"8G"``); the physical memory of the machine. A limit of
``0`` (or ``"none"``) switches the check off.
"""

from __future__ import annotations

import os

import torch

__all__ = [
    "memory_limit", "set_memory_limit", "check_memory", "format_bytes", "itemsize", "check_rows",
]

_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
_limit: int | None = None  # set_memory_limit; None: environment or physical memory


def _parse(text: str) -> int:
    t = text.strip().upper().removesuffix("IB").removesuffix("B")
    if t in ("NONE", "OFF"):
        return 0
    unit = t[-1:] if t[-1:] in _UNITS and t[-1:] else ""
    number = t[: len(t) - len(unit)]
    try:
        value = float(number) * _UNITS[unit]
    except ValueError:
        raise ValueError(
            f"TORCHTOF_MEMORY_LIMIT: expected bytes such as '8G', '512M' or 'none', got {text!r}"
        ) from None
    if not value >= 0 or value == float("inf"):
        raise ValueError(f"TORCHTOF_MEMORY_LIMIT: expected a size >= 0, got {text!r}")
    return int(value)


def _physical() -> int:
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        return 0


def memory_limit() -> int:
    """The current limit in bytes (0: no check)."""
    if _limit is not None:
        return _limit
    env = os.environ.get("TORCHTOF_MEMORY_LIMIT")
    if env:
        return _parse(env)
    return _physical()


def set_memory_limit(limit: int | str | None) -> None:
    """Set the limit for :func:`check_memory`: bytes (int), a string such as ``"8G"``,
    ``0``/``"none"`` for no check, or ``None`` to go back to the environment variable /
    physical memory."""
    global _limit
    if limit is None:
        _limit = None
    elif isinstance(limit, str):
        _limit = _parse(limit)
    elif isinstance(limit, bool) or not isinstance(limit, int):
        raise TypeError(
            f"set_memory_limit: expected limit to be an int, a string or None, "
            f"got {type(limit).__name__}"
        )
    elif limit < 0:
        raise ValueError(f"set_memory_limit: expected limit >= 0, got {limit}")
    else:
        _limit = limit


def format_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n} PiB"  # pragma: no cover


def check_memory(nbytes: float, what: str, func: str, hint: str = "") -> None:
    """Raise ``ValueError`` if ``nbytes`` exceeds :func:`memory_limit`.

    Args:
        nbytes: the estimated peak of the allocation.
        what: what would be allocated (shown in the message).
        func: the public entry point (message prefix).
        hint: what the user can change (appended to the message).
    """
    limit = memory_limit()
    if limit and nbytes > limit:
        tail = f"; {hint}" if hint else ""
        raise ValueError(
            f"{func}: {what} needs about {format_bytes(nbytes)}, more than the memory limit "
            f"of {format_bytes(limit)} (torchtof.set_memory_limit or TORCHTOF_MEMORY_LIMIT)"
            f"{tail}"
        )


def itemsize(dtype: torch.dtype, func: str = "itemsize") -> int:
    """Bytes per element of ``dtype`` (``TypeError`` naming ``func`` if it is no dtype)."""
    if not isinstance(dtype, torch.dtype):
        raise TypeError(f"{func}: expected dtype to be a torch.dtype, got {type(dtype).__name__}")
    return torch.empty((), dtype=dtype).element_size()


def check_rows(start: object, stop: object, total: int, func: str) -> tuple[int, int]:
    """``0 <= start <= stop <= total`` as ints (``stop=None``: ``total``)."""
    stop = total if stop is None else stop
    for name, v in (("start", start), ("stop", stop)):
        if isinstance(v, bool) or not isinstance(v, int):
            raise TypeError(f"{func}: expected {name} to be an int, got {type(v).__name__}")
    if not 0 <= start <= stop <= total:
        raise ValueError(
            f"{func}: expected 0 <= start <= stop <= {total}, got start={start}, stop={stop}"
        )
    return start, stop
