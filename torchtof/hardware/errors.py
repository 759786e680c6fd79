"""Errors of the hardware layer: each says what failed and what the user can do about it.

``HardwareError`` is the base. :class:`TransientError` marks faults that a retry can fix (a
NACK, a frame timeout, a corrupt or out-of-sequence frame); :func:`torchtof.hardware.acquire`
retries those and re-raises them after ``retries`` attempts. A vanished device
(:class:`DeviceLostError`) is never retried: the run stops and ``--resume`` continues it.
"""

from __future__ import annotations

__all__ = [
    "UDEV_HINT",
    "HardwareError",
    "TransientError",
    "DeviceNotFoundError",
    "DeviceBusyError",
    "DeviceLostError",
    "ProtocolError",
    "NackError",
    "FrameTimeoutError",
    "FrameError",
    "FrameSequenceError",
    "FrameIdError",
    "FrameTimingError",
    "usb_exceptions",
]

#: How to give a non-root user access to the two USB devices (Linux).
UDEV_HINT = (
    "On Linux, non-root access needs a udev rule, e.g. /etc/udev/rules.d/99-torchtof.rules with\n"
    '  SUBSYSTEM=="usb", ATTR{idVendor}=="0451", ATTR{idProduct}=="6401", MODE="0666"\n'
    '  SUBSYSTEM=="usb", ATTR{idVendor}=="0451", ATTR{idProduct}=="9105", MODE="0666"\n'
    "then `sudo udevadm control --reload-rules && sudo udevadm trigger` and re-plug the device. "
    "Check that it is listed by `lsusb -d 0451:`."
)


class HardwareError(RuntimeError):
    """Base class of every hardware-layer error."""


class TransientError(HardwareError):
    """A fault that a retry may fix (NACK, timeout, corrupt or out-of-sequence frame)."""


class DeviceNotFoundError(HardwareError):
    """No device with the expected USB vendor/product id (or no USB backend)."""

    def __init__(self, what: str, vid: int, pid: int, detail: str = "") -> None:
        self.what, self.vid, self.pid = what, vid, pid
        extra = f" ({detail})" if detail else ""
        super().__init__(
            f"no {what} found (USB {vid:04x}:{pid:04x}){extra}. Is it plugged in and powered? "
            f"{UDEV_HINT}"
        )


class DeviceBusyError(HardwareError):
    """The device exists but another process (or a kernel driver) holds its interface."""

    def __init__(self, what: str, detail: str = "") -> None:
        self.what = what
        super().__init__(
            f"{what} is busy: another program holds its USB interface ({detail}). Close the "
            "vendor GUI or the other torchtof process; on Linux a kernel HID driver is detached "
            f"automatically only with write access to the device. {UDEV_HINT}"
        )


class DeviceLostError(HardwareError):
    """The device disappeared during a run (unplugged, powered off, reset)."""

    def __init__(self, what: str, detail: str = "") -> None:
        self.what = what
        super().__init__(
            f"{what} disappeared during the run ({detail}). Re-connect it and run the same "
            "command with --resume (acquire(..., resume=True)) to continue where it stopped."
        )


class ProtocolError(HardwareError):
    """A malformed or unexpected reply to a named command."""

    def __init__(self, command: str, detail: str) -> None:
        self.command = command
        super().__init__(f"{command}: {detail}")


class NackError(ProtocolError, TransientError):
    """The device answered a command with NACK (the error flag of its reply)."""

    def __init__(self, command: str, detail: str = "") -> None:
        super().__init__(command, f"device answered NACK{': ' + detail if detail else ''}")


class FrameTimeoutError(TransientError):
    """No frame arrived in time for the pattern with index ``pattern_index``."""

    def __init__(self, pattern_index: int | None, timeout_s: float, detail: str = "") -> None:
        self.pattern_index = pattern_index
        where = f"pattern {pattern_index}" if pattern_index is not None else "a frame"
        extra = f" ({detail})" if detail else ""
        super().__init__(
            f"frame timeout: no ToF frame for {where} within {timeout_s:g} s{extra}. Check the "
            "trigger cable (DMD TRIG_OUT1 -> camera trigger in) and the exposure/period."
        )


class FrameError(TransientError):
    """A frame whose bytes do not decode (wrong size, reserved bits set, values out of range)."""

    def __init__(self, detail: str, pattern_index: int | None = None) -> None:
        self.pattern_index = pattern_index
        where = f" for pattern {pattern_index}" if pattern_index is not None else ""
        super().__init__(f"corrupt frame{where}: {detail}")


class FrameSequenceError(TransientError):
    """More frames than patterns in a sequence (the count check of
    :func:`~torchtof.hardware.acquire`: a lost frame shows as a missing one — a timeout — and
    an extra frame as this error); the acquisition re-acquires the sequence."""

    def __init__(self, expected: int, got: int, pattern_index: int | None = None) -> None:
        self.expected, self.got, self.pattern_index = expected, got, pattern_index
        where = f" in the sequence from pattern {pattern_index}" if pattern_index is not None \
            else ""
        super().__init__(f"{got} frame(s){where}, expected {expected}")


class FrameIdError(TransientError):
    """A device frame id (OPT9221 ``debug_frame_number_en``) that does not follow its
    predecessor: a gap (frames lost between camera and host) or a repeated id on a frame with
    different bytes; the acquisition re-acquires the whole sequence."""

    def __init__(self, pattern_index: int, expected: int, got: int, detail: str = "") -> None:
        self.pattern_index, self.expected, self.got = pattern_index, expected, got
        what = detail or f"{(got - expected) % 256} frame(s) lost"
        super().__init__(f"frame id {got} for pattern {pattern_index}, expected {expected} "
                         f"({what})")


class FrameTimingError(TransientError):
    """A frame whose host arrival time does not fit the pattern schedule (a spurious frame
    arrives too early, a lost one leaves a gap); the acquisition re-acquires the sequence."""

    def __init__(self, pattern_index: int, expected_s: float, got_s: float) -> None:
        self.pattern_index, self.expected_s, self.got_s = pattern_index, expected_s, got_s
        super().__init__(f"frame for pattern {pattern_index} arrived {got_s * 1e3:.1f} ms after "
                         f"the sequence's first, expected {expected_s * 1e3:.1f} ms (a spurious "
                         "or lost frame)")


class _USBError(OSError):
    """Stand-in for pyusb's ``usb.core.USBError`` (same constructor and attributes) when pyusb
    is not installed: the simulator raises it, the drivers translate it."""

    def __init__(self, strerror: str, error_code: int | None = None,
                 errno: int | None = None) -> None:
        super().__init__(errno, strerror)
        self.backend_error_code = error_code


class _USBTimeoutError(_USBError):
    """Stand-in for pyusb's ``usb.core.USBTimeoutError``."""


def usb_exceptions() -> tuple[type[OSError], type[OSError]]:
    """``(USBError, USBTimeoutError)``: pyusb's ``usb.core`` classes when pyusb is installed,
    else stand-ins with the same constructor. The simulated devices raise these and the
    drivers catch them, so ``torchtof acquire --simulated`` (no USB) runs without pyusb; the
    real devices need pyusb (:func:`~torchtof.hardware.dlpc350.find_device` names the extra).
    """
    try:
        import usb.core
    except ImportError:
        return _USBError, _USBTimeoutError
    return usb.core.USBError, usb.core.USBTimeoutError
