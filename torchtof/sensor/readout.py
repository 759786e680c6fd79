"""The ToF camera's on-chip readout: the four taps → amplitude, phase and depth.

This is the noise-free second half of :func:`~torchtof.sensor.cw_tof_sensor` (which calls it
after drawing the noise): it starts from the measured real taps, so it also runs on recorded
frames and exports to ONNX (which cannot carry the complex phasors the sensor starts from).
The defaults are :func:`~torchtof.sensor.cw_tof_sensor`'s; the paper's camera rounds to
``step_m=0.25``.
"""

from __future__ import annotations

import torch
from torch import nn

from .._checks import check_positive, check_shape, check_tensor
from .functional import (
    camera_rules,
    check_rules_config,
    phase_to_depth,
    tap_amplitude,
    tap_phase,
)

__all__ = ["camera_readout", "CameraReadout"]


def camera_readout(
    taps: torch.Tensor,
    *,
    freq_hz: float = 30e6,
    min_m: float = 1.0,
    max_m: float = 5.0,
    amp_threshold: float = 0.0,
    no_photon_m: float = 5.0,
    step_m: float | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Taps → ``(amplitude, phase, depth)`` as the camera computes them (paper §2.1–2.2).

    Amplitude by Eq. 8 (:func:`~torchtof.sensor.functional.tap_amplitude`), phase by Eq. 7
    (:func:`~torchtof.sensor.functional.tap_phase`, Fig. 1 tap order), depth by Eq. 1
    (:func:`~torchtof.sensor.functional.phase_to_depth`) followed by the camera rules of §2.2
    (:func:`~torchtof.sensor.functional.camera_rules`): clip to ``[min_m, max_m]``, round to
    ``step_m``, ``no_photon_m`` where the amplitude is ``<= amp_threshold``.

    Args:
        taps: real taps ``(B, 4, H, W)`` in the Fig. 1 order (``τ = 0, π, π/2, 3π/2``).
        freq_hz, min_m, max_m, amp_threshold, no_photon_m, step_m: as in
            :func:`~torchtof.sensor.functional.camera_rules` and
            :func:`~torchtof.sensor.functional.phase_to_depth`.

    Returns:
        ``(amplitude, phase, depth)``, each ``(B, 1, H, W)``.

    Raises:
        TypeError, ValueError: as the sensor functions (wrong shape, dtype, parameters).

    Example:
        >>> from torchtof.sensor.functional import correlation_taps, phasor_from_depth
        >>> p = phasor_from_depth(100.0, torch.full((1, 1, 2, 2), 2.0), 30e6)
        >>> amp, phase, depth = camera_readout(correlation_taps(p, offset=60.0))
        >>> round(depth[0, 0, 0, 0].item(), 4), round(amp[0, 0, 0, 0].item(), 3)
        (2.0, 50.0)
    """
    func = "camera_readout"  # its own name in the errors of what it is given
    check_tensor(taps, "taps", func)
    check_shape(taps, (None, 4, None, None), "taps", func, "(B, 4, H, W)")
    check_positive(freq_hz, "freq_hz", func)
    amplitude = tap_amplitude(taps)
    phase = tap_phase(taps)
    depth = camera_rules(
        phase_to_depth(phase, freq_hz), amplitude, min_m, max_m, amp_threshold, no_photon_m, step_m
    )
    return amplitude, phase, depth


class CameraReadout(nn.Module):
    """Module of :func:`camera_readout`: ``forward(taps) -> (amplitude, phase, depth)``.

    Holds the configuration (keyword arguments of :func:`camera_readout`, validated here;
    :attr:`config` returns them); no buffers or parameters.

    Example:
        >>> CameraReadout(step_m=0.25).config["step_m"]
        0.25
    """

    def __init__(
        self,
        freq_hz: float = 30e6,
        min_m: float = 1.0,
        max_m: float = 5.0,
        amp_threshold: float = 0.0,
        no_photon_m: float = 5.0,
        step_m: float | None = None,
    ) -> None:
        super().__init__()
        self.config = dict(freq_hz=freq_hz, min_m=min_m, max_m=max_m,
                           amp_threshold=amp_threshold, no_photon_m=no_photon_m, step_m=step_m)
        # the checks of the functions forward calls, named after this class
        check_positive(freq_hz, "freq_hz", "CameraReadout")
        check_rules_config("CameraReadout", min_m, max_m, amp_threshold, no_photon_m, step_m)

    def forward(self, taps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return camera_readout(taps, **self.config)

    def extra_repr(self) -> str:
        return ", ".join(f"{k}={v!r}" for k, v in self.config.items())
