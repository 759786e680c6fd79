"""Real hardware: a DLP LightCrafter 4500 and a TI OPT8241 ToF camera over USB (pyusb),
simulated stand-ins for both, and safe, resumable acquisition into zarr (README "Real
hardware").

``import torchtof`` does not import this package; importing it does not import pyusb
either — the submodules load on first use (``torchtof.hardware.acquire`` …), and pyusb
only when a device is opened or a USB error is translated; the simulated devices run without
pyusb (:func:`~torchtof.hardware.errors.usb_exceptions`). (The acquisition code lives in
``acquisition.py`` so that ``torchtof.hardware.acquire`` is the function, not a module.)
"""

from __future__ import annotations

import importlib

__all__ = [
    "acquire",
    "load_run",
    "load_buckets",
    "Frame",
    "FrameSource",
    "LightCrafter4500",
    "OPT8241",
    "CameraRules",
    "SimulatedBench",
    "Faults",
    "StoreDamagedError",
    "WindowVideoPort",
    "errors",
    "dlpc350",
    "opt8241",
    "frames",
    "simulated",
    "video",
]

_LAZY = {
    "acquire": ("acquisition", "acquire"),
    "load_run": ("acquisition", "load_run"),
    "load_buckets": ("acquisition", "load_buckets"),
    "Frame": ("frames", "Frame"),
    "FrameSource": ("frames", "FrameSource"),
    "LightCrafter4500": ("dlpc350", "LightCrafter4500"),
    "OPT8241": ("opt8241", "OPT8241"),
    "CameraRules": ("opt8241", "CameraRules"),
    "SimulatedBench": ("simulated", "SimulatedBench"),
    "Faults": ("simulated", "Faults"),
    "StoreDamagedError": ("acquisition", "StoreDamagedError"),
    "WindowVideoPort": ("video", "WindowVideoPort"),
}
_MODULES = {"errors", "dlpc350", "opt8241", "frames", "simulated", "acquisition", "cli",
            "video", "throughput"}


def __getattr__(name: str):
    if name in _LAZY:
        mod, attr = _LAZY[name]
        return getattr(importlib.import_module(f".{mod}", __name__), attr)
    if name in _MODULES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
