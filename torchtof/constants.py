"""Constants shared by the package, defined once.

Example:
    >>> from torchtof.constants import PAPER_SRS, SPEED_OF_LIGHT
    >>> SPEED_OF_LIGHT, PAPER_SRS[0]
    (299792458.0, 0.0625)
"""

from __future__ import annotations

__all__ = ["SPEED_OF_LIGHT", "DISCREPANCY_TAU", "PAPER_SRS"]

#: Speed of light in vacuum, m/s (exact by the SI definition of the metre, 1983).
SPEED_OF_LIGHT = 299_792_458.0
#: Morozov's safety factor ``τ`` of the discrepancy principle ``‖A x − y‖² ≤ τ M σ²``
#: (Morozov 1966), used by every solver that stops at the noise level.
DISCREPANCY_TAU = 1.0
#: The paper's sampling rates (Figs. 5, 7–13).
PAPER_SRS: tuple[float, ...] = (0.0625, 0.125, 0.1875, 0.25, 0.3125, 0.375)
