"""Stray light and the differential buckets (paper §3.1, Eqs. 5-10).

Pattern-independent stray light adds the same phasor to every frame. The four correlation
taps are linear in the returned light (Eqs. 5-6), so the tap buckets' ``y⁺ − y⁻`` cannot
depend on it at all; a depth value is the phase of the phasor sum (Eq. 7), a non-linear
function, so the depth buckets' ``y⁺ − y⁻`` must change when stray light is added.
"""

import torch

from torchtof.experiment import PaperExperiment

QUIET = dict(shot=None, read_noise_e=0.0, adc_bits=None)


def _measure(stray_e: float, kind: str, gate: bool = False) -> torch.Tensor:
    exp = PaperExperiment(sr=1.0, n=8, roi_px=16, srs=(1.0,), stray_e=stray_e, **QUIET)
    data = exp.run(seed=0, dtype=torch.float64)
    return data.measurements(1.0, kind=kind, gate=gate)[1]


def test_tap_differentials_do_not_see_stray_light():
    clean, stray = _measure(0.0, "taps"), _measure(1000.0, "taps")
    assert clean.abs().max() > 0
    torch.testing.assert_close(stray, clean, rtol=1e-9, atol=1e-9 * clean.abs().max().item())


def test_depth_differentials_do_see_stray_light():
    for gate in (False, True):
        clean, stray = _measure(0.0, "depth", gate), _measure(1000.0, "depth", gate)
        rel = (stray - clean).norm() / clean.norm()
        assert rel > 0.1, f"gate={gate}: depth differentials moved only {rel:.3g}"
