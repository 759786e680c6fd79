"""Imports of the optional dependencies, each with the install extra that provides it.

``pip install torchtof`` needs only torch, kornia, numpy, scipy and scikit-image. The
features below need an extra; importing one without it raises an ``ImportError`` that names
the extra, e.g. ``pip install 'torchtof[onnx]'``.
"""

from __future__ import annotations

import importlib
import platform
import sys
from types import ModuleType

__all__ = ["EXTRAS", "require", "progress_bar"]

#: module → the extra of ``pyproject.toml`` that installs it.
EXTRAS = {
    "onnx": "onnx",
    "onnxruntime": "onnx",
    "onnxscript": "onnx",
    "usb": "hardware",
    "zarr": "hardware",
    "pygame": "hardware",
    "matplotlib": "plot",
    "tqdm": "all",
}


def require(module: str, feature: str) -> ModuleType:
    """Import ``module`` or raise an ``ImportError`` naming the extra that installs it.

    Args:
        module: the top-level module name, a key of :data:`EXTRAS`.
        feature: what needs it, for the message (e.g. ``"torchtof.onnx"``).

    Example:
        >>> require("numpy", "a doctest").__name__
        'numpy'
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        extra = EXTRAS.get(module.split(".")[0], "all")
        hint = ""
        if module.split(".")[0] == "zarr" and sys.version_info < (3, 11):
            # the hardware extra pins zarr >= 3.1.6, which exists for Python >= 3.11 only
            hint = f" (zarr >= 3.1.6 needs Python >= 3.11; this is {platform.python_version()})"
        raise ImportError(
            f"{feature} needs the optional package {module!r}: pip install 'torchtof[{extra}]'"
            + hint
        ) from exc


class _NoBar:
    """Stand-in for a tqdm bar when tqdm is not installed: counts, prints nothing."""

    def __init__(self, iterable=None, total=None, **_):
        self.iterable, self.total, self.n = iterable, total, 0

    def __iter__(self):
        yield from self.iterable or ()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def update(self, k: int = 1) -> None:
        self.n += k

    def set_postfix_str(self, *_, **__) -> None:
        pass

    def set_description(self, *_, **__) -> None:
        pass

    def write(self, s: str, **_) -> None:
        print(s)

    def close(self) -> None:
        pass


def progress_bar(iterable=None, **kwargs):
    """``tqdm.auto.tqdm(iterable, **kwargs)`` (a bar on stderr), or a silent stand-in with
    the same ``update``/``set_postfix_str``/``close`` methods when tqdm is not installed.

    Example:
        >>> sum(progress_bar(range(3), disable=True))
        3
    """
    try:
        from tqdm.auto import tqdm
    except ImportError:  # tqdm is optional
        return _NoBar(iterable, kwargs.get("total"))
    return tqdm(iterable, **kwargs)
