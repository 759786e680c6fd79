"""Reconstructors: every one an ``nn.Module`` with ``forward(y (B, C, M)) -> x (B, C, n, n)``.

:func:`get` and :func:`names` read the one table of reconstructors (:mod:`.registry`).
"""

from .auto import Auto, AutoResult, auto  # noqa: E402,I001
from .base import ReconResult
from .bp import BasisPursuit, BPResult, basis_pursuit
from .correlation import CGI, DGI, TGI, cgi, dgi, g2, tgi
from .dct import DCT2, Haar2, dct2, haar2, idct2, ihaar2
from .depth import (
    DepthResolved,
    DepthResult,
    DualFrequencyDepth,
    JointTV,
    common_range,
    depth_resolved,
    dual_frequency_depth,
    hypothesis_spacing,
    iq_buckets,
    iq_phase_amplitude,
    joint_tv,
    tap_noise_sigma,
)
from .dip import DIP, DIPResult, auto_zeta, default_unet, dip, dip_input, fit_dip
from .learned import Learned, LearnedResult, learned
from .pinv import PseudoInverse, pseudo_inverse
from .registry import REGISTRY, ReconSpec, get, names
from .tgv import TGV, TGVResult, tgv
from .train import TrainResult, train_unrolled
from .tval3 import TVAL3, TVAL3Result, bucket_noise_sigma, tval3
from .unet import UNet
from .unrolled import UnrolledTVAL3, unrolled_tval3

__all__ = [
    "ReconResult",
    "REGISTRY",
    "ReconSpec",
    "get",
    "names",
    "CGI",
    "DGI",
    "TGI",
    "cgi",
    "dgi",
    "g2",
    "tgi",
    "PseudoInverse",
    "pseudo_inverse",
    "BasisPursuit",
    "BPResult",
    "basis_pursuit",
    "TVAL3",
    "Auto",
    "AutoResult",
    "auto",
    "Learned",
    "LearnedResult",
    "learned",
    "TVAL3Result",
    "TGV",
    "TGVResult",
    "tgv",
    "tval3",
    "bucket_noise_sigma",
    "UnrolledTVAL3",
    "unrolled_tval3",
    "train_unrolled",
    "TrainResult",
    "UNet",
    "DIP",
    "DIPResult",
    "dip",
    "fit_dip",
    "dip_input",
    "default_unet",
    "auto_zeta",
    "DCT2",
    "Haar2",
    "dct2",
    "idct2",
    "haar2",
    "ihaar2",
    "DepthResolved",
    "DepthResult",
    "DualFrequencyDepth",
    "JointTV",
    "depth_resolved",
    "dual_frequency_depth",
    "hypothesis_spacing",
    "common_range",
    "iq_buckets",
    "iq_phase_amplitude",
    "joint_tv",
    "tap_noise_sigma",
]
