"""torchtof: depth imaging with time-of-flight cameras as bucket detectors of computational
ghost imaging, as PyTorch modules (see the README)."""

from . import bucket, experiment, metrics, operators, recon, scenes, sensor
from ._memory import memory_limit, set_memory_limit
from .experiment import PaperExperiment

__version__ = "0.1.0"

__all__ = [
    "operators",
    "sensor",
    "bucket",
    "recon",
    "metrics",
    "scenes",
    "experiment",
    "PaperExperiment",
    "set_memory_limit",
    "memory_limit",
    "__version__",
]
