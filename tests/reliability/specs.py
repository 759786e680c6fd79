"""The public calls the bad-input matrix misuses, each with one valid argument set."""

from __future__ import annotations

import torch

from torchtof import bucket, metrics, scenes, sensor
from torchtof.experiment import PaperExperiment
from torchtof.operators import (
    DMDSplit,
    Hadamard,
    PatternOperator,
    combine_split,
    fwht,
    gaussian_speckle_patterns,
    hadamard_order,
    hadamard_patterns,
    random_binary_patterns,
    split_patterns,
    sylvester,
)

from .matrix import NAN, Spec, T

INF = float("inf")


def _g(seed: int = 0) -> torch.Generator:
    return torch.Generator().manual_seed(seed)


def _rand(*shape, seed=0, lo=0.0, hi=1.0):
    return lo + (hi - lo) * torch.rand(*shape, generator=_g(seed))


def _phasor(b=2, h=4, w=4, seed=0):
    return sensor.phasor_from_depth(_rand(b, 1, h, w, seed=seed, lo=50, hi=100),
                                    _rand(b, 1, h, w, seed=seed + 1, lo=1, hi=4), 30e6)


# one operator of each kind, built once (their construction is a spec of its own)
_H = Hadamard(8, sr=0.5)
_S = DMDSplit(_H)
_P = PatternOperator(random_binary_patterns(20, 8, generator=_g(3)))

SIZES = [0, -4, 1.5, "8", True]
POS = [0.0, -1.0, NAN, INF, "1"]
NONNEG = [-1.0, NAN, INF, "1"]

SPECS: list[Spec] = [
    # ------------------------------------------------------------------ operators
    Spec("operators: Hadamard()", "operators", Hadamard,
         lambda: dict(n=8, sr=0.5),
         bad={"n": [0, -8, 12, 8.0, "8", 512], "sr": [0.0, -0.1, 1.5, NAN, "0.5"]}),
    Spec("operators: Hadamard.forward", "operators", _H.forward,
         lambda: dict(x=_rand(2, 1, 8, 8)), {"x": T()}, linear=True),
    Spec("operators: Hadamard.adjoint", "operators", _H.adjoint,
         lambda: dict(y=_rand(2, 1, 32, lo=-1)), {"y": T()}, linear=True),
    Spec("operators: Hadamard.patterns", "operators", _H.patterns,
         lambda: dict(start=0, stop=4),
         bad={"start": [-1, 1.5, 40], "stop": [33, "4"], "dtype": ["float32", None]}),
    Spec("operators: PatternOperator()", "operators", PatternOperator,
         lambda: dict(patterns=_rand(6, 4, 4)), {"patterns": T(batch=False)}, batch0=False),
    Spec("operators: PatternOperator.forward", "operators",
         _P.forward, lambda: dict(x=_rand(2, 1, 8, 8)), {"x": T()}, linear=True),
    Spec("operators: PatternOperator.adjoint", "operators",
         _P.adjoint, lambda: dict(y=_rand(2, 1, 20)), {"y": T()}, linear=True),
    Spec("operators: PatternOperator.pinv", "operators",
         _P.pinv, lambda: dict(y=_rand(2, 1, 20)), {"y": T()}, linear=True),
    Spec("operators: DMDSplit.forward", "operators", _S.forward,
         lambda: dict(x=_rand(2, 1, 8, 8)), {"x": T()}, linear=True),
    Spec("operators: DMDSplit.adjoint", "operators", _S.adjoint,
         lambda: dict(y=_rand(2, 1, 64)), {"y": T()}, linear=True),
    Spec("operators: DMDSplit.patterns", "operators", _S.patterns,
         lambda: dict(start=1, stop=7),
         bad={"start": [-1, 2.0, 70], "stop": [65], "dtype": ["float32"]}),
    Spec("operators: combine_split", "operators", combine_split,
         lambda: dict(y_split=_rand(2, 1, 8), n=8), {"y_split": T()}, linear=True),
    Spec("operators: split_patterns", "operators", split_patterns,
         lambda: dict(patterns=hadamard_patterns(4, 3)), {"patterns": T(batch=False)},
         batch0=False),
    Spec("operators: fwht", "operators", fwht,
         lambda: dict(x=_rand(2, 8)), {"x": T(any_rank=True)}, linear=True),
    Spec("operators: sylvester", "operators", sylvester, lambda: dict(n=8),
         bad={"n": SIZES + [12]}),
    Spec("operators: hadamard_order", "operators", hadamard_order,
         lambda: dict(n=8), bad={"n": SIZES, "order": ["zigzag", 3]}),
    Spec("operators: hadamard_patterns", "operators", hadamard_patterns,
         lambda: dict(n=8, m=4), bad={"n": SIZES, "m": [0, -1, 65, 2.5, "4"]}),
    Spec("operators: random_binary_patterns", "operators",
         random_binary_patterns, lambda: dict(m=4, n=8, generator=_g()),
         bad={"m": SIZES, "n": SIZES, "p": [0.0, 1.0, NAN, "0.5"]}),
    Spec("operators: gaussian_speckle_patterns", "operators",
         gaussian_speckle_patterns, lambda: dict(m=4, n=8, generator=_g()),
         bad={"m": SIZES, "n": SIZES, "grain": [-1.0, NAN, INF]}),
    # ------------------------------------------------------------------ sensor
    Spec("sensor: phasor_from_depth", "sensor", sensor.phasor_from_depth,
         lambda: dict(amplitude=_rand(2, 1, 4, 4, lo=1, hi=2), depth_m=_rand(2, 1, 4, 4, lo=1,
                                                                            hi=4), freq_hz=30e6),
         {"amplitude": T(any_rank=True), "depth_m": T(any_rank=True)},
         bad={"freq_hz": POS}),
    Spec("sensor: correlation_taps", "sensor", sensor.correlation_taps,
         lambda: dict(phasor=_phasor(), offset=1.0), {"phasor": T(complex_in=True)},
         bad={"order": ["zigzag"]}),
    Spec("sensor: tap_phase", "sensor", sensor.tap_phase,
         lambda: dict(taps=_rand(2, 4, 4, 4, hi=100)), {"taps": T()}),
    Spec("sensor: tap_amplitude", "sensor", sensor.tap_amplitude,
         lambda: dict(taps=_rand(2, 4, 4, 4, hi=100)), {"taps": T()}),
    Spec("sensor: phase_to_depth", "sensor", sensor.phase_to_depth,
         lambda: dict(phase=_rand(2, 1, 4, 4, hi=6), freq_hz=30e6),
         {"phase": T(any_rank=True)}, linear=False, bad={"freq_hz": POS}),
    Spec("sensor: camera_rules", "sensor", sensor.camera_rules,
         lambda: dict(depth=_rand(2, 1, 4, 4, hi=6), amplitude=_rand(2, 1, 4, 4, seed=1)),
         {"depth": T(), "amplitude": T()},
         bad={"min_m": [-1.0, NAN], "max_m": [0.5, INF], "step_m": [0.0, -0.25, NAN]}),
    Spec("sensor: shot_noise", "sensor", sensor.shot_noise,
         lambda: dict(taps=_rand(2, 4, 4, 4, hi=100), generator=_g()), {"taps": T()},
         random=True, bad={"mode": ["laplace", None]}),
    Spec("sensor: read_noise", "sensor", sensor.read_noise,
         lambda: dict(taps=_rand(2, 4, 4, 4, hi=100), sigma_e=2.0, generator=_g()),
         {"taps": T()}, random=True, bad={"sigma_e": NONNEG}),
    Spec("sensor: adc_quantize", "sensor", sensor.adc_quantize,
         lambda: dict(taps=_rand(2, 4, 4, 4, hi=100)), {"taps": T()},
         bad={"bits": [0, 33, 12.0, "12"], "gain_e_per_dn": POS}),
    Spec("sensor: tof_noise", "sensor", sensor.tof_noise,
         lambda: dict(taps=_rand(2, 4, 4, 4, hi=100), generator=_g()), {"taps": T()},
         random=True, bad={"gain_e_per_dn": POS, "read_noise_e": NONNEG,
                           "full_well_e": [0.0, -1.0, NAN], "adc_bits": [0, 40, 1.5]}),
    Spec("sensor: cw_tof_sensor", "sensor", sensor.cw_tof_sensor,
         lambda: dict(phasor=_phasor(), generator=_g()), {"phasor": T(complex_in=True)},
         random=True, bad={"freq_hz": POS, "gain_e_per_dn": POS, "ambient_e": NONNEG,
                           "min_m": [NAN, -1.0], "step_m": [0.0, NAN]}),
    Spec("sensor: dmd_to_sensor", "sensor", sensor.dmd_to_sensor,
         lambda: dict(x=_rand(2, 1, 4, 4), out_hw=6), {"x": T()}, linear=True,
         bad={"out_hw": SIZES + [(6,), (6, 0)]}),
    Spec("sensor: blur_phasor", "sensor", sensor.blur_phasor,
         lambda: dict(x=_rand(2, 1, 8, 8), sigma_px=1.0), {"x": T()}, linear=True,
         bad={"sigma_px": [-1.0, NAN, INF, "1"]}),
    Spec("sensor: add_multipath", "sensor", sensor.add_multipath,
         lambda: dict(phasor=_phasor(), strength=0.3, extra_path_m=1.0),
         {"phasor": T(complex_in=True)},
         bad={"strength": [-0.1, NAN], "extra_path_m": [NAN, INF], "freq_hz": POS}),
    Spec("sensor: dust_map", "sensor", sensor.dust_map,
         lambda: dict(size=8, generator=_g()), bad={"size": SIZES, "sigma_px": [-1.0, NAN]}),
    Spec("sensor: scatter_depth", "sensor", sensor.scatter_depth,
         lambda: dict(depth=_rand(2, 1, 4, 4, lo=1, hi=4), alpha=0.6, depth_s=0.2),
         {"depth": T()}, bad={"alpha": [0.0, 1.5, NAN], "depth_s": [-1.0, NAN]}),
    Spec("sensor: scatter_phasor", "sensor", sensor.scatter_phasor,
         lambda: dict(phasor=_phasor(), alpha=0.6, blur_sigma=1.0, backscatter=2.0),
         {"phasor": T(complex_in=True)},
         bad={"alpha": [0.0, 1.5, NAN], "blur_sigma": [-1.0, NAN], "backscatter": [NAN],
              "sheet_m": [NAN, -1.0]}),
    # ------------------------------------------------------------------ metrics
    Spec("metrics: psnr", "metrics", metrics.psnr,
         lambda: dict(x_hat=_rand(2, 1, 8, 8), x=_rand(2, 1, 8, 8, seed=1)),
         {"x_hat": T(), "x": T()},
         bad={"bits": [0, 65, 8.0, "8"], "max_db": [0.0, NAN], "reduction": ["sum"]}),
    Spec("metrics: ssim", "metrics", metrics.ssim,
         lambda: dict(x_hat=_rand(2, 1, 8, 8), x=_rand(2, 1, 8, 8, seed=1)),
         {"x_hat": T(), "x": T()},
         bad={"data_range": [0.0, -1.0, NAN, INF], "window_size": [4, 1, 17, 7.0]}),
    Spec("metrics: depth_rmse", "metrics", metrics.depth_rmse,
         lambda: dict(depth_hat=_rand(2, 1, 4, 4), depth=_rand(2, 1, 4, 4, seed=1)),
         {"depth_hat": T(), "depth": T()},
         bad={"mask": [torch.zeros(4, 4, dtype=torch.bool), torch.ones(3, 3, dtype=torch.bool),
                       torch.ones(4, 4)]}),
    Spec("metrics: normalize_image", "metrics", metrics.normalize_image,
         lambda: dict(x=_rand(2, 1, 4, 4, lo=-3, hi=5)), {"x": T()}, bad={"mode": ["zscore"]}),
    Spec("metrics: resolve_sign", "metrics", metrics.resolve_sign,
         lambda: dict(x_hat=_rand(2, 1, 4, 4), polarity="auto",
                      reference=_rand(2, 1, 4, 4, seed=1)),
         {"x_hat": T(), "reference": T()}, bad={"polarity": ["up", None]}),
    Spec("metrics: affine_fit", "metrics", metrics.affine_fit,
         lambda: dict(x_hat=_rand(2, 1, 4, 4), x=_rand(2, 1, 4, 4, seed=1)),
         {"x_hat": T(), "x": T()}),
    Spec("metrics: compare", "metrics", metrics.compare,
         lambda: dict(x_hat=_rand(2, 1, 8, 8), x=_rand(2, 1, 8, 8, seed=1)),
         {"x_hat": T(), "x": T()}, bad={"polarity": ["up"], "bits": [0, 2.5]}),
    # ------------------------------------------------------------------ scenes
    Spec("scenes: sky_character", "scenes", scenes.sky_character,
         lambda: dict(n=16), bad={"n": SIZES + [4]}),
    Spec("scenes: depth_scene", "scenes", scenes.depth_scene,
         lambda: dict(object_mask=(_rand(1, 1, 8, 8) > 0.5).float(), object_m=2.0),
         {"object_mask": T()}, bad={"object_m": POS, "background_m": [NAN, -1.0]}),
    Spec("scenes: depth_steps", "scenes", scenes.depth_steps,
         lambda: dict(n=16), bad={"n": SIZES, "seed": [1.5, -1, "0"],
                                  "levels": [(2.0,), (2.0, NAN), (2.0, -1.0)]}),
    Spec("scenes: slanted_plane", "scenes", scenes.slanted_plane,
         lambda: dict(n=16), bad={"n": SIZES, "near_m": [NAN, -1.0, 4.0],
                                  "angle_deg": [NAN, INF]}),
    Spec("scenes: skimage_scene", "scenes", scenes.skimage_scene,
         lambda: dict(name="camera", n=16), bad={"name": ["lena", 3], "n": SIZES}),
    Spec("scenes: binary_scene", "scenes", scenes.binary_scene,
         lambda: dict(name="horse", n=16), bad={"name": ["zebra"], "n": SIZES}),
    Spec("scenes: motorcycle_depth", "scenes", scenes.motorcycle_depth,
         lambda: dict(n=16), bad={"n": SIZES, "near_m": [NAN, 0.0], "far_m": [0.5]}),
    Spec("scenes: get_scene", "scenes", scenes.get_scene,
         lambda: dict(name="sky", n=16),
         bad={"name": ["moon", 3, None], "n": SIZES, "object_m": POS}),
    # ------------------------------------------------------------------ bucket
    Spec("bucket: roi_mask", "bucket", bucket.roi_mask,
         lambda: dict(shape_hw=(8, 8), roi=(1, 1, 4, 4)),
         bad={"shape_hw": [(0, 8), (8,), (8.0, 8)], "roi": [(1, 1, 0, 4), (6, 6, 4, 4),
                                                          (1, 1, 4), "all"]}),
    Spec("bucket: depth_gate", "bucket", bucket.depth_gate,
         lambda: dict(depth=_rand(2, 3, 4, 4, lo=1, hi=5)), {"depth": T()},
         bad={"gate_m": POS}),
    Spec("bucket: depth_bucket", "bucket", bucket.depth_bucket,
         lambda: dict(depth=_rand(2, 3, 4, 4, lo=1, hi=5), roi=(0, 0, 2, 2)), {"depth": T()},
         bad={"gate_m": POS, "roi": [(0, 0, 5, 5), (0, 0, 0, 1), (0, 0, 2.0, 2)]}),
    Spec("bucket: intensity_bucket", "bucket", bucket.intensity_bucket,
         lambda: dict(amplitude=_rand(2, 3, 4, 4)), {"amplitude": T()}, linear=True,
         bad={"roi": [(0, 0, 5, 5), "all"]}),
    Spec("bucket: tap_buckets", "bucket", bucket.tap_buckets,
         lambda: dict(taps=_rand(2, 3, 4, 4, 4)), {"taps": T()}, linear=True,
         bad={"roi": [(0, 0, 5, 5)]}),
    # ------------------------------------------------------------------ experiment
    Spec("experiment: PaperExperiment()", "experiment", PaperExperiment,
         lambda: dict(sr=0.125, n=8, roi_px=8, srs=(0.125,)),
         bad={"sr": [0.0, 1.5, NAN, "0.1"], "n": [0, 12, 8.0], "roi_px": [4, 0, 8.5],
              "chunk_frames": [0, -1, 2.5], "gain_e_per_dn": [0.0, -1.0, NAN],
              "alpha": [0.0, 2.0], "signal_e": [NAN, -1.0], "srs": [(), (0.0,), "0.1"],
              "scene": ["moon"], "shot": ["laplace"], "adc_bits": [0, 2.5],
              "step_m": [0.0, NAN]}),
    Spec("experiment: PaperExperiment.run", "experiment",
         PaperExperiment(sr=0.125, n=8, roi_px=8, srs=(0.125,)).run,
         lambda: dict(seed=0), bad={"seed": [1.5, "0", None], "realisations": [0, -1, 1.5],
                                    "dtype": [torch.float16, torch.int64, "float32"]}),
]


def _cgi():
    from torchtof.recon import CGI

    return CGI(_S).forward


def _dgi():
    from torchtof.recon import DGI

    return DGI(_S).forward


# Calls outside the modules above, from the defects we were told of; their failing cases are
# marked xfail(strict=True) in the test so that they flip when fixed.
OUTSIDE: list[Spec] = [
    Spec("recon: CGI.forward", "recon", lambda y: _cgi()(y),
         lambda: dict(y=_rand(2, 1, 64)), {"y": T()}, aliases=("cgi",)),
    Spec("recon: DGI.forward", "recon", lambda y: _dgi()(y),
         lambda: dict(y=_rand(2, 1, 64)), {"y": T()}, aliases=("dgi",)),
]
