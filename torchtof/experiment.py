"""The paper's experiment as one configurable object (paper §3).

A binary object (the character 天, 32×32) at 2 m is imaged onto a DMD that shows Hadamard
patterns as complementary 0/1 pairs (``φ⁺ = (1+h)/2``, ``φ⁻ = (1−h)/2``); a CW-ToF camera
(30 MHz, 64×64 ROI, Poisson shot + read noise, 12-bit ADC, the camera rules of §2.2) looks
at the DMD, optionally through a dusty scattering sheet; each depth map is summed over the
ROI into one bucket (Eq. 10), with and without the 3 m depth gate (§3.1).

Per frame ``i`` and sensor pixel ``p`` the light is a sum of phasors:

1. object light through the DMD, ``s · O(u) φ_i(u) e^{j4πf z(u)/c}`` on the DMD grid,
   imaged onto the ROI by area overlap (:func:`~torchtof.sensor.dmd_to_sensor`) and an
   optical PSF (Gaussian, ``psf_sigma_px``), which mixes phasors at edges (mixed pixels);
2. multipath: a weak, widely spread copy of that light delayed by ``multipath_extra_m``
   (stray reflections inside the relay optics) — it lights dark pixels at a depth beyond
   the 3 m gate, one of the noise sources the paper names in §3.1;
3. through the sheet (``scattering=True``): the phasor model ``P' = α·(G * P) + b·dust·
   e^{j4πf d_s/c}`` (:func:`~torchtof.sensor.scatter_phasor`), or the paper's depth-domain
   Eq. 15 ``D' = αD + Dˢ`` with ``scattering_model="depth"``.

The camera adds the ambient offset, shot and read noise, digitises the taps, computes phase
(Eq. 7), amplitude (Eq. 8) and depth (Eq. 1) and applies the rules: clip to [1, 5] m,
"no photon" (amplitude below threshold) → 5 m, 0.25 m output step.

``scattering_model="depth"`` applies the paper's Eq. 15 to the Eq. 1 depth of each pixel
*before* these rules (:func:`~torchtof.sensor.scatter_depth`, then
:func:`~torchtof.sensor.camera_rules`), so the depth stays in the camera's output domain: in
``[min_m, max_m]`` on the ``step_m`` grid, and a pixel without photons still reports
``max_m`` (5 m), which the 3 m gate removes. The model is phenomenological — it describes the
camera's depth map, not the light — so it leaves the taps, the amplitude and the phase of the
frames, hence the tap and intensity buckets, as they are in air; only the ``"phasor"`` model
scatters the light itself.

**Comparing a depth image with the binary object** (the paper's "ToF image", Fig. 5b): the
raw ToF depth map is taken with every mirror on, averaged over the sensor pixels of each
DMD pixel onto the 32×32 grid, and scored with :func:`torchtof.metrics.compare`: min-max
normalisation, polarity from the physics (raw depth maps and ungated depth-bucket images are
*negative*: ``1 − minmax``; gated images positive), PSNR on the 8-bit scale (Eqs. 13–14).
The stray light (``stray_e``, light that reaches the camera in every frame) was calibrated to
bring this raw image near the paper's 5.70 dB (``examples/calibrate_noise.py`` reproduces the
sweep); with the defaults it scores 6.5–6.6 dB (``torchtof.methods.raw_tof_scores``, two
realisations, seeds 0 and 1). Nothing else was tuned to the paper.

Smaller sampling rates are prefixes of the largest one (the Hadamard order is fixed), so one
simulation at ``max(srs)`` serves every SR.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import torch

from ._checks import (
    check_finite,
    check_in_range,
    check_int,
    check_positive,
    check_power_of_two,
    check_shape,
    unchecked,
)
from ._memory import check_memory
from .bucket import depth_bucket, intensity_bucket, tap_buckets
from .constants import PAPER_SRS  # the paper's sampling rates, re-exported
from .operators import DMDSplit, Hadamard
from .operators.patterns import ORDERS, num_patterns
from .scenes import Scene, get_scene
from .sensor import (
    add_multipath,
    blur_phasor,
    camera_rules,
    cw_tof_sensor,
    dmd_to_sensor,
    dust_map,
    phase_to_depth,
    phasor_from_depth,
    scatter_depth,
    scatter_phasor,
)

__all__ = [
    "PAPER_SRS",
    "PAPER_PSNR",
    "ExperimentConfig",
    "ExperimentData",
    "PaperExperiment",
    "simulate_frames",
    "stray_light",
    "frame_memory",
]


#: PSNR (dB) the paper reports (§3, Figs. 7, 9, 11, 13): (case, SR) -> {method: dB}.
PAPER_PSNR: dict[tuple[str, float], dict[str, float]] = {
    ("air", 0.125): {"CGI": 8.23, "BP": 7.64, "TVAL3": 8.52, "raw ToF": 5.70},
    ("air", 0.25): {"CGI": 9.44, "BP": 9.76, "TVAL3": 9.82, "raw ToF": 5.70},
    ("air+gate", 0.0625): {"DIP": 11.42, "raw ToF": 5.70},
    ("air+gate", 0.25): {"CGI": 9.44, "BP": 9.76, "TVAL3": 9.82, "DIP": 11.39, "raw ToF": 5.70},
    ("scatter", 0.125): {"CGI": 5.09, "BP": 4.91, "TVAL3": 6.17},
    ("scatter", 0.25): {"CGI": 6.16, "BP": 6.05, "TVAL3": 6.81},
    ("scatter+gate", 0.0625): {"CGI": 7.03, "BP": 7.46, "TVAL3": 7.52, "DIP": 9.01},
    ("scatter+gate", 0.25): {"CGI": 9.59, "BP": 9.84, "TVAL3": 10.21, "DIP": 11.73},
}


@dataclass(frozen=True)
class ExperimentConfig:
    """Physical parameters of the simulated set-up (units in the names; e⁻ = photo-electrons).

    The defaults are the paper's set-up (§3); ``stray_e`` is the calibrated value that brings
    the raw ToF depth image near the paper's 5.70 dB (6.5–6.6 dB with these defaults).
    """

    n: int = 32
    scene: str = "sky"
    object_m: float = 2.0
    roi_px: int = 64
    freq_hz: float = 30e6
    order: str = "cake_cutting"
    # light and camera
    signal_e: float = 400.0  # modulated amplitude |P| of a fully lit sensor pixel
    ambient_e: float = 2600.0  # ambient-light offset per tap
    read_noise_e: float = 12.0
    shot: str | None = "poisson"  # shot noise: "poisson", "gaussian" or None (noise-free)
    adc_bits: int | None = 12
    gain_e_per_dn: float | None = None  # None: auto exposure (see gain())
    amp_threshold_e: float = 120.0  # Eq. 8 amplitude below this -> "no photon" -> 5 m
    step_m: float | None = 0.25
    min_m: float = 1.0
    max_m: float = 5.0
    psf_sigma_px: float = 0.6  # optical blur on the sensor (mixed pixels)
    multipath_strength: float = 0.35
    multipath_extra_m: float = 1.6
    multipath_sigma_px: float = 6.0  # spread of the multipath copy; 0: none (same pixel)
    stray_e: float = 1000.0  # peak amplitude of pattern-independent stray returns (calibrated)
    stray_near_m: float = 2.3
    stray_far_m: float = 4.9  # >= stray_near_m
    stray_sigma_px: float = 3.0  # correlation length of the stray maps, > 0
    stray_seed: int = 11
    # scattering sheet
    scattering: bool = False
    scattering_model: str = "phasor"
    alpha: float = 0.6
    scatter_sigma_px: float = 2.0
    backscatter_e: float = 700.0  # peak backscatter amplitude (dust map maximum)
    sheet_m: float = 1.2
    depth_s_m: float = 0.4  # Eq. 15's Dˢ scale for the depth-domain model
    dust_sigma_px: float = 6.0  # correlation length of the dust map, > 0
    dust_seed: int = 7
    # acquisition
    srs: tuple[float, ...] = PAPER_SRS
    gate_m: float = 3.0
    chunk_frames: int = 256

    def gain(self) -> float:
        """ADC gain in e⁻/DN: ``gain_e_per_dn``, or (``None``) the exposure control of the
        camera: the brightest tap (ambient + full signal + 4σ shot noise) at 3/4 of full scale."""
        if self.gain_e_per_dn is not None:
            return float(self.gain_e_per_dn)
        top = self.ambient_e + self.signal_e * (1 + self.multipath_strength) + self.stray_e
        top += 4 * math.sqrt(top)
        return top / (0.75 * (2 ** (self.adc_bits or 12) - 1))

    def validate(self, func: str = "ExperimentConfig") -> ExperimentConfig:
        """``self`` if every field is valid; errors name ``func`` (the caller the user
        called, e.g. ``PaperExperiment``) and the field."""
        check_power_of_two(self.n, "n", func, lo=4, hi=256)
        if self.order not in ORDERS:
            raise ValueError(f"{func}: expected order in {ORDERS}, got {self.order!r}")
        for name in ("roi_px", "chunk_frames"):
            check_int(getattr(self, name), name, func, lo=1)
        for name in ("stray_seed", "dust_seed"):
            check_int(getattr(self, name), name, func)
        if self.adc_bits is not None:
            check_int(self.adc_bits, "adc_bits", func, lo=1, hi=32)
        if self.gain_e_per_dn is not None:
            check_positive(self.gain_e_per_dn, "gain_e_per_dn", func)
        if self.step_m is not None:
            check_positive(self.step_m, "step_m", func)
        for name in ("min_m", "max_m", "sheet_m", "multipath_extra_m", "stray_near_m",
                     "stray_far_m", "multipath_sigma_px"):
            check_positive(getattr(self, name), name, func, strict=False)
        # correlation lengths of the smooth random stray and dust maps (dust_map): > 0
        for name in ("stray_sigma_px", "dust_sigma_px"):
            check_positive(getattr(self, name), name, func)
        if not self.max_m > self.min_m:
            raise ValueError(f"{func}: expected max_m > min_m, got min_m={self.min_m}, "
                             f"max_m={self.max_m}")
        if not self.stray_far_m >= self.stray_near_m:
            raise ValueError(f"{func}: expected stray_far_m >= stray_near_m, got "
                             f"stray_near_m={self.stray_near_m}, stray_far_m={self.stray_far_m}")
        if not isinstance(self.scattering, bool):
            raise TypeError(f"{func}: expected scattering to be a bool, got "
                            f"{type(self.scattering).__name__}")
        for name in ("signal_e", "freq_hz", "object_m", "gate_m"):
            check_positive(getattr(self, name), name, func)
        for name in ("ambient_e", "stray_e", "read_noise_e", "amp_threshold_e",
                     "multipath_strength", "backscatter_e", "depth_s_m", "psf_sigma_px",
                     "scatter_sigma_px"):
            check_positive(getattr(self, name), name, func, strict=False)
        check_in_range(self.alpha, 0.0, 1.0, "alpha", func, lo_open=True)
        if self.shot not in (None, "poisson", "gaussian"):
            raise ValueError(f"{func}: expected shot in (None, 'poisson', 'gaussian'), "
                             f"got {self.shot!r}")
        if self.scattering_model not in ("phasor", "depth"):
            raise ValueError(
                f"{func}: expected scattering_model in ('phasor', 'depth'), "
                f"got {self.scattering_model!r}"
            )
        _check_scene_name(self.scene, func)
        if not isinstance(self.srs, (tuple, list)) or not self.srs:
            raise ValueError(f"{func}: expected at least one sampling rate in srs, got {self.srs}")
        for sr in self.srs:
            check_in_range(sr, 0.0, 1.0, "srs", func, lo_open=True)
        if len(set(self.srs)) != len(self.srs):
            raise ValueError(f"{func}: expected distinct sampling rates in srs, got {self.srs}")
        if self.roi_px < self.n:
            raise ValueError(f"{func}: expected roi_px >= n ({self.n}), got {self.roi_px}")
        return self


#: Peak bytes per (frame × sensor pixel × byte of the real dtype) of one chunk of
#: :func:`simulate_frames` plus the bucket sums: the growth of the maximum resident set size
#: was 53–58× at n = 64 with (roi_px, chunk_frames) = (128, 256) and (256, 64)
#: (tests/reliability/measure_memory.py, docs/reliability.md); rounded up to 64.
FRAME_BYTES_FACTOR = 64


def frame_memory(cfg: ExperimentConfig, frames: int, dtype: torch.dtype = torch.float32) -> int:
    """Estimated peak bytes of simulating ``frames`` frames at once (one chunk of
    :meth:`PaperExperiment.run`): ``FRAME_BYTES_FACTOR · frames · roi_px² · itemsize``."""
    item = torch.empty((), dtype=dtype).element_size()
    return FRAME_BYTES_FACTOR * frames * cfg.roi_px**2 * item


def _check_scene_name(name: object, func: str) -> None:
    from .scenes import SCENES

    ok = isinstance(name, str) and (name in SCENES or name.startswith(("skimage:", "binary:")))
    if not ok:
        raise ValueError(f"{func}: expected scene in {SCENES} or 'skimage:<name>'/'binary:<name>', "
                         f"got {name!r}")


def _smooth(x: torch.Tensor, sigma: float) -> torch.Tensor:
    return x if sigma <= 0 else blur_phasor(x, sigma)


def stray_light(cfg: ExperimentConfig, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Pattern-independent stray returns on the sensor, complex ``(1, 1, P, P)``.

    Light that reaches the camera without passing the DMD's on-mirrors — the environment,
    reflections off the relay optics and the DMD frame, multipath (paper §3.1, Fig. 6:
    background pixels at 4.978 m) — is the same in every frame. A smooth random amplitude
    map (peak ``stray_e``) at smooth random depths in ``[stray_near_m, stray_far_m]``, seeded by
    ``stray_seed``. It ruins the raw depth map but cancels in the differential buckets
    ``y⁺ − y⁻`` (up to the sensor's non-linearity), which is why CGI beats the raw image.
    """
    g = torch.Generator().manual_seed(cfg.stray_seed)
    amp = dust_map(cfg.roi_px, cfg.stray_sigma_px, g, dtype=dtype)
    depth = dust_map(cfg.roi_px, 2 * cfg.stray_sigma_px, g, dtype=dtype)
    depth = cfg.stray_near_m + (cfg.stray_far_m - cfg.stray_near_m) * depth
    return phasor_from_depth(cfg.stray_e * amp, depth, cfg.freq_hz)


def simulate_frames(
    scene: Scene,
    patterns: torch.Tensor,
    cfg: ExperimentConfig,
    generator: torch.Generator | None = None,
    dust: torch.Tensor | None = None,
    stray: torch.Tensor | None = None,
):
    """ToF frames of the scene seen through DMD patterns (the forward model of the module doc).

    Args:
        scene: reflectance and depth ``(1, 1, n, n)``.
        patterns: 0/1 DMD patterns ``(F, n, n)`` (one frame each).
        cfg: the set-up.
        generator: noise generator.
        dust: ``(1, 1, P, P)`` dust map in [0, 1] for the sheet (scattering only).
        stray: complex ``(1, 1, P, P)`` pattern-independent stray phasor (:func:`stray_light`).

    Returns:
        :class:`~torchtof.sensor.ToFFrame` with ``(F, ·, P, P)`` tensors.

    Raises:
        TypeError: if ``patterns``, ``dust`` or ``stray`` is not a tensor.
        ValueError: if the scene is not ``(1, 1, n, n)``, ``patterns`` not ``(F, n, n)``,
            ``dust`` or ``stray`` not ``(1, 1, P, P)``, ``dust`` missing with
            ``cfg.scattering``, or any of them holds NaN or Inf.
    """
    func = "simulate_frames"
    n, p = cfg.n, cfg.roi_px
    for name, t in (("scene.reflectance", scene.reflectance), ("scene.depth_m", scene.depth_m)):
        check_shape(t, (1, 1, n, n), name, func, f"(1, 1, n, n), n = cfg.n = {n}")
    check_shape(patterns, (None, n, n), "patterns", func, f"(F, n, n), n = cfg.n = {n}")
    for name, t in (("dust", dust), ("stray", stray)):
        if t is not None:  # (check_shape checks the tensor and its dtype first)
            check_shape(t, (1, 1, p, p), name, func, f"(1, 1, P, P), P = cfg.roi_px = {p}")
    if cfg.scattering and dust is None:
        raise ValueError(f"{func}: cfg.scattering needs the sheet's dust map: pass dust "
                         f"(1, 1, {p}, {p}) (ScatteringMedium.dust_map)")
    for name, t in (("scene.reflectance", scene.reflectance), ("scene.depth_m", scene.depth_m),
                    ("patterns", patterns), ("dust", dust), ("stray", stray)):
        if t is not None:
            check_finite(t, name, func)
    # validated once here: the sensor chain below skips its per-call finiteness checks (each a
    # host read; a simulated bench renders one frame per call)
    with unchecked():
        return _frames(scene, patterns, cfg, generator, dust, stray)


def _frames(scene, patterns, cfg, generator, dust, stray):
    p = cfg.roi_px
    refl = scene.reflectance * patterns[:, None]  # (F, 1, n, n) light leaving each mirror
    phasor = phasor_from_depth(cfg.signal_e * refl, scene.depth_m.expand_as(refl), cfg.freq_hz)
    # incoherent (unmodulated) light follows the same linear optics: I = Σ|a_j| / 2
    mag = cfg.signal_e * refl
    if cfg.multipath_strength > 0:
        # The optics are linear, so the widely spread stray light is computed on the DMD grid
        # (σ scaled by n/P) before imaging onto the sensor, ~8x cheaper. Not the same result:
        # blurring and the area mapping do not commute exactly (4 % relative L2 on the sky
        # character at n = 32, P = 64, σ = 6 px), a modelling choice for a smooth halo.
        sigma = cfg.multipath_sigma_px * cfg.n / p
        phasor = add_multipath(phasor, cfg.multipath_strength, cfg.multipath_extra_m, cfg.freq_hz,
                               sigma or None)  # 0: an unspread copy (the config's comment)
        mag = mag + cfg.multipath_strength * _smooth(mag, sigma)
    phasor = _smooth(dmd_to_sensor(phasor, p), cfg.psf_sigma_px)
    mag = _smooth(dmd_to_sensor(mag, p), cfg.psf_sigma_px)
    if stray is not None:  # pattern-independent returns: the same in every frame
        phasor = phasor + stray
        mag = mag + stray.abs()
    if cfg.scattering and cfg.scattering_model == "phasor":
        b = cfg.backscatter_e * dust
        phasor = scatter_phasor(phasor, cfg.alpha, cfg.scatter_sigma_px or None, b,
                                cfg.sheet_m, cfg.freq_hz)
        mag = cfg.alpha * _smooth(mag, cfg.scatter_sigma_px) + b
    g = cfg.gain() if cfg.adc_bits is not None else 1.0
    rules = dict(min_m=cfg.min_m, max_m=cfg.max_m, amp_threshold=cfg.amp_threshold_e / g,
                 no_photon_m=cfg.max_m, step_m=cfg.step_m)
    frame = cw_tof_sensor(
        phasor, 0.5 * mag, freq_hz=cfg.freq_hz, ambient_e=cfg.ambient_e, shot=cfg.shot,
        read_noise_e=cfg.read_noise_e, adc_bits=cfg.adc_bits, gain_e_per_dn=g,
        generator=generator, **rules,
    )
    if cfg.scattering and cfg.scattering_model == "depth":
        # Eq. 15 on the Eq. 1 depth, then the camera's rules (module docstring): the output
        # keeps the camera's [min_m, max_m] clip, step grid and no-photon depth
        depth = scatter_depth(phase_to_depth(frame.phase, cfg.freq_hz), cfg.alpha,
                              cfg.depth_s_m * dust)
        frame = frame._replace(depth=camera_rules(depth, frame.amplitude, **rules))
    return frame


@dataclass
class ExperimentData:
    """What one run of the experiment produces (``R`` noise realisations in the batch axis).

    Attributes:
        config: the set-up.
        x: the object ``(1, 1, n, n)`` (binary reflectance; the ground truth).
        depth_m: the object's depth map ``(1, 1, n, n)``.
        raw_tof: raw ToF depth maps with every mirror on ``(R, 1, P, P)`` (paper Fig. 5b).
        raw_tof_image: ``raw_tof`` averaged onto the DMD grid ``(R, 1, n, n)``.
        buckets: interleaved ``φ⁺/φ⁻`` buckets at the largest SR, ``(R, C, 2M)``:
            ``"depth"`` (Eq. 10, no gate), ``"depth_gated"`` (§3.1 gate), ``"intensity"``
            (Eq. 8 amplitude sums) with ``C = 1``, and ``"taps"`` with ``C = 4``.
        hadamard: the ±1 operator at the largest SR.
    """

    config: ExperimentConfig
    x: torch.Tensor
    depth_m: torch.Tensor
    raw_tof: torch.Tensor
    raw_tof_image: torch.Tensor
    buckets: dict[str, torch.Tensor]
    hadamard: Hadamard
    timings: dict[str, float] = field(default_factory=dict)

    def m(self, sr: float) -> int:
        """Number of ±1 patterns at ``sr``."""
        return num_patterns(self.config.n, sr=sr, func="ExperimentData")

    def operator(self, sr: float) -> Hadamard:
        """The orthonormal ±1 Hadamard operator at ``sr`` (a prefix of the acquired order)."""
        m = self.m(sr)
        if m > self.hadamard.m:
            raise ValueError(
                f"ExperimentData: sr={sr} needs {m} patterns, the run acquired {self.hadamard.m}"
            )
        return Hadamard(self.config.n, m=m, order=self.config.order)

    def split_operator(self, sr: float) -> DMDSplit:
        """The 0/1 DMD operator (``2M`` rows) at ``sr``: the patterns the camera saw."""
        return DMDSplit(self.operator(sr))

    def split_buckets(self, sr: float, kind: str = "depth", gate: bool = False) -> torch.Tensor:
        """Interleaved DMD buckets ``(R, C, 2M)`` at ``sr`` (``gate`` selects the gated depth).

        Raises:
            TypeError: ``gate`` is not a bool.
            ValueError: an unknown ``kind``, ``gate=True`` with a kind other than
                ``"depth"`` (the depth gate applies to the depth buckets only), or an ``sr``
                above the largest one the run acquired.
        """
        _check_kind_gate(kind, gate)
        key = "depth_gated" if (kind == "depth" and gate) else kind
        if gate and kind != "depth":
            raise ValueError(f"ExperimentData: gate=True applies to the depth buckets only (the "
                             f"{self.config.gate_m:g} m depth gate), got kind={kind!r}")
        m = self.m(sr)
        if m > self.hadamard.m:
            raise ValueError(
                f"ExperimentData: sr={sr} needs {m} patterns, the run acquired {self.hadamard.m}"
            )
        return self.buckets[key][..., : 2 * m]

    def measurements(self, sr: float, kind: str = "depth", gate: bool = False):
        """``(A, y)``: the ±1 operator and ``y = (y⁺ − y⁻)/n`` ``(R, C, M)`` at ``sr``
        (``gate=True``: the gated depth buckets; a ValueError with any other ``kind``)."""
        s = self.split_operator(sr)
        return s.hadamard, s.combine(self.split_buckets(sr, kind, gate))

    def polarity(self, gate: bool, kind: str = "depth") -> str:
        """Physics polarity of images from these buckets (paper §3.1): ungated depth → negative."""
        _check_kind_gate(kind, gate)
        return "negative" if (kind == "depth" and not gate) else "positive"


#: The bucket kinds of :meth:`ExperimentData.split_buckets` (``"depth_gated"`` is ``"depth"``
#: with ``gate=True``).
KINDS = ("depth", "intensity", "taps")


def _check_kind_gate(kind: object, gate: object) -> None:
    if not isinstance(gate, bool):
        raise TypeError(f"ExperimentData: expected gate to be a bool, got {type(gate).__name__}")
    if kind not in KINDS:
        raise ValueError(f"ExperimentData: expected kind in {KINDS}, got {kind!r}")


class PaperExperiment:
    """The paper's CGI experiment with a ToF camera as bucket detector.

    Args:
        sr: the sampling rate the demo reconstructs at (must be ≤ the largest of ``srs``).
        scattering: put the dusty sheet in the path (paper §3.2).
        gate_m: depth gate ("low-pass filter") in metres (paper: 3).
        **overrides: any :class:`ExperimentConfig` field (``n``, ``scene``, ``alpha`` …).

    Example:
        >>> exp = PaperExperiment(sr=0.125, n=16, roi_px=32, srs=(0.125,))
        >>> data = exp.run(seed=0, realisations=1)
        >>> A, y = data.measurements(0.125, gate=True)
        >>> y.shape
        torch.Size([1, 1, 32])
    """

    def __init__(
        self, sr: float = 0.125, scattering: bool = False, gate_m: float = 3.0, **overrides
    ) -> None:
        unknown = set(overrides) - set(ExperimentConfig.__dataclass_fields__)
        if unknown:
            raise TypeError(f"PaperExperiment: unknown arguments {sorted(unknown)}")
        cfg = ExperimentConfig(scattering=scattering, gate_m=gate_m, **overrides).validate(
            "PaperExperiment")
        check_in_range(sr, 0.0, 1.0, "sr", "PaperExperiment", lo_open=True)
        if sr not in cfg.srs:
            cfg = replace(cfg, srs=tuple(sorted(set(cfg.srs) | {sr})))
        self.sr = sr
        self.config = cfg

    def scene(self, dtype: torch.dtype = torch.float32) -> Scene:
        return get_scene(self.config.scene, self.config.n, self.config.object_m, dtype=dtype)

    def run(
        self, seed: int = 0, realisations: int = 1, dtype: torch.dtype = torch.float32,
        progress: bool = False,
    ) -> ExperimentData:
        """Simulate the raw ToF image and every bucket at the largest SR, ``realisations``
        independent noise draws (batch axis)."""
        import time

        cfg = self.config
        func = "PaperExperiment.run"
        check_int(realisations, "realisations", func, lo=1)
        check_int(seed, "seed", func, lo=-(2**63), hi=2**64 - 1)  # torch.Generator's range
        if dtype not in (torch.float32, torch.float64):
            raise TypeError(f"{func}: expected dtype torch.float32 or torch.float64, got {dtype}")
        t0 = time.perf_counter()
        gen = torch.Generator().manual_seed(seed)
        scene = self.scene(dtype)
        n, p = cfg.n, cfg.roi_px
        dust = None
        if cfg.scattering:
            dust = dust_map(p, cfg.dust_sigma_px, torch.Generator().manual_seed(cfg.dust_seed),
                            dtype=dtype)
        stray = stray_light(cfg, dtype) if cfg.stray_e > 0 else None
        hadamard = Hadamard(n, sr=max(cfg.srs), order=cfg.order)
        split = DMDSplit(hadamard)  # 2M patterns in acquisition order, built per chunk
        n_frames = split.m
        check_memory(frame_memory(cfg, min(cfg.chunk_frames, n_frames), dtype),
                     f"simulating {min(cfg.chunk_frames, n_frames)} frames of "
                     f"{p}x{p} sensor pixels at a time", func, "lower chunk_frames or roi_px")
        keys = ("depth", "depth_gated", "intensity", "taps")
        out: dict[str, list[torch.Tensor]] = {k: [] for k in keys}
        raw = []
        chunks = range(0, n_frames, cfg.chunk_frames)
        bar = None
        if progress:
            from ._optional import progress_bar as tqdm

            bar = tqdm(total=realisations * len(chunks), desc="simulating ToF frames",
                       leave=False)
        for _ in range(realisations):
            parts = {k: [] for k in keys}
            for start in chunks:
                pats = split.patterns(dtype, start, min(start + cfg.chunk_frames, n_frames))
                fr = simulate_frames(scene, pats, cfg, gen, dust, stray)
                depth = fr.depth[:, 0][None]  # (1, F, P, P): frames on the frame axis
                parts["depth"].append(depth_bucket(depth))
                parts["depth_gated"].append(depth_bucket(depth, gate_m=cfg.gate_m))
                parts["intensity"].append(intensity_bucket(fr.amplitude[:, 0][None]))
                parts["taps"].append(tap_buckets(fr.taps[None]))
                if bar is not None:
                    bar.update(1)
            for k in keys:
                out[k].append(torch.cat(parts[k], dim=-1))
            ones = torch.ones(1, n, n, dtype=dtype)
            raw.append(simulate_frames(scene, ones, cfg, gen, dust, stray).depth)
        if bar is not None:
            bar.close()
        raw_tof = torch.cat(raw)
        k = p // n
        if p % n == 0:
            raw_img = torch.nn.functional.avg_pool2d(raw_tof, k)
        else:
            raw_img = torch.nn.functional.interpolate(raw_tof, size=(n, n), mode="area")
        buckets = {k_: torch.cat(v) for k_, v in out.items()}
        return ExperimentData(
            config=cfg, x=scene.reflectance, depth_m=scene.depth_m, raw_tof=raw_tof,
            raw_tof_image=raw_img, buckets=buckets, hadamard=hadamard,
            timings={"simulate_s": time.perf_counter() - t0},
        )

    def __repr__(self) -> str:
        d = asdict(self.config)
        keep = ("n", "scene", "roi_px", "scattering", "alpha", "gate_m", "ambient_e")
        return "PaperExperiment(sr={}, {})".format(
            self.sr, ", ".join(f"{k}={d[k]}" for k in keep)
        )

