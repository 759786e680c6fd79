"""CW-ToF sensor model: correlation taps, noise, camera rules, mixing, multipath, scattering.

See the paper's §2.1–2.2 (Eqs. 1–8) and Eq. 15 (scattering).
"""

from .functional import (
    SPEED_OF_LIGHT,
    TAP_ORDERS,
    camera_rules,
    correlation_taps,
    phase_to_depth,
    phasor_from_depth,
    tap_amplitude,
    tap_phase,
    unambiguous_range,
)
from .mixing import DMDToSensor, area_overlap_matrix, blur_phasor, dmd_to_sensor
from .multipath import Multipath, add_multipath
from .noise import SHOT_MODES, ToFNoise, adc_quantize, read_noise, shot_noise, tof_noise
from .readout import CameraReadout, camera_readout
from .scattering import (
    SCATTER_MODES,
    ScatteringMedium,
    dust_map,
    scatter_depth,
    scatter_phasor,
    scattering_medium,
)
from .tof import CWToFSensor, ToFFrame, cw_tof_sensor

__all__ = [
    # functional core (Eqs. 1-8, §2.2)
    "SPEED_OF_LIGHT",
    "TAP_ORDERS",
    "unambiguous_range",
    "phasor_from_depth",
    "correlation_taps",
    "tap_phase",
    "tap_amplitude",
    "phase_to_depth",
    "camera_rules",
    # noise
    "SHOT_MODES",
    "shot_noise",
    "read_noise",
    "adc_quantize",
    "tof_noise",
    "ToFNoise",
    # sensor
    "ToFFrame",
    "cw_tof_sensor",
    "CWToFSensor",
    "camera_readout",
    "CameraReadout",
    # mixing / multipath
    "area_overlap_matrix",
    "dmd_to_sensor",
    "DMDToSensor",
    "blur_phasor",
    "add_multipath",
    "Multipath",
    # scattering (Eq. 15)
    "SCATTER_MODES",
    "dust_map",
    "scatter_depth",
    "scatter_phasor",
    "scattering_medium",
    "ScatteringMedium",
]
