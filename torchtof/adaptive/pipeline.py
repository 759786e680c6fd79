"""The adaptive pipeline against the fixed one, on a recorded or simulated run.

**Fixed pipeline** (the paper's §3): every pattern up to the maximum SR, the 3 m
depth gate (§3.1), the veil compensation of Eq. 15 (``y/α̂``; ``Dˢ`` cancels in ``y⁺ − y⁻``),
and the reconstructor run to its own convergence.

**Adaptive pipeline** (:func:`run_adaptive`):

1. the first DMD pair (all-on, dark) → :func:`~torchtof.adaptive.detect.detect_veil` and
   :func:`~torchtof.adaptive.detect.detect_far_background`;
2. the noise level (``noise="pairs"``, the default): no extra patterns, ``σ̂`` from the pair
   sums ``(y⁺ + y⁻)/n`` of all pairs so far
   (:func:`~torchtof.adaptive.noise.noise_from_pair_sums`; biased up 1.0–1.25× on the depth
   buckets, README), re-estimated after every block, ``τ`` from its effective degrees of
   freedom. ``noise="repeat"``: the second block is measured twice (``repeat=True``,
   ``B = block`` extra patterns — fewer when the record ends inside the second block —
   counted in ``patterns_used``) and
   ``σ̂² = ‖y_b − y'_b‖²/(2B)`` per bucket kind (not the first block: its all-on/dark pair
   is noisier or quieter than the rest). The pair sums are the default since the
   per-seed benchmark (README): with repeats the 32 extra patterns alone put the paper's
   character over half the patterns on 5 of 7 seeds;
3. the gate: kept with a veil or a far background, or when
   :func:`~torchtof.adaptive.detect.gate_changes_image` (F test, 99 %; with pair sums the
   successive differences stand in for repeats, on their ``ν ≈ 0.67 K`` degrees of freedom)
   finds on the first 128 patterns that it changes the image beyond the noise; skipped
   otherwise (ungated buckets,
   negative images, §3.1). A record of fewer than 8 patterns is too short for the F test
   (:data:`~torchtof.adaptive.detect.GATE_MIN_BUCKETS`): the test is skipped (``skipped``
   says so) and the gate kept, as in the fixed pipeline. The veil compensation runs only
   with a veil, and is refused (``ValueError``) for ``α̂ <= 0``;
4. progressive acquisition with :class:`~torchtof.adaptive.progressive.ProgressiveStop`
   (innovation rule at ``σ̂``) on the chosen buckets (``stop_kind="auto"``). With a fixed
   ``stop_kind`` (e.g. ``"depth"``) the stop no longer depends on the gate, which is then
   decided on all ``m`` patterns acquired (the gate is per-frame processing: it costs no
   frames). Stopping on the ungated buckets was tried and stops the dense scenes too early
   for their gated image (grey photo −0.2…−1.3 dB on seeds 0–5, README);
5. the reconstructor — TVAL3 by default, or the cheapest one meeting a budget
   (:func:`~torchtof.adaptive.budget.choose_method`) — stopped by the discrepancy principle
   (:func:`~torchtof.adaptive.solvers.solve_at_noise`) at ``τ M σ̂²`` with ``τ = q``, the
   95 % lower confidence limit of ``σ²/σ̂²`` (``q = B/χ²_B(0.95)`` = 0.69 for ``B = 32``,
   :func:`~torchtof.adaptive.noise.variance_lower_factor`): ``σ̂²`` from ``B`` repeats is
   ±25 % off, and an over-estimate stopped TVAL3 before it had fitted the signal. ``σ̂``
   also feeds TVAL3's ``mu="auto"`` model choice (``model_sigma=True``, as before).
   ``model_sigma=False`` (TVAL3's own tail estimate picks the model, as in the fixed
   pipeline) was better for the small object at ten times the light (calibration seed 10:
   −0.5 against −2.6 dB) and worse at the paper's light level (grey photo −0.0 against
   +1.0 dB, 天 behind the sheet −0.6 against +0.1 dB), so it is an option, not the default.

Time: acquisition is one ToF frame per DMD pattern (two per ±1 row) at ``fps`` frames per
second (the paper's camera: 30–150 fps); compute is measured wall time.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import torch

from .._checks import cache_build, check_bool, check_int, check_number, check_positive
from .budget import MethodChoice, choose_method
from .detect import (
    GATE_MIN_BUCKETS,
    DarkReference,
    FarEstimate,
    VeilEstimate,
    dark_reference,
    detect_far_background,
    detect_veil,
    gate_changes_image,
)
from .noise import (
    noise_from_pair_sums,
    pair_differences,
    pair_noise_dof,
    pair_sums,
    variance_lower_factor,
)
from .progressive import ProgressiveResult, ProgressiveStop, run_progressive
from .solvers import SOLVERS, solve_at_noise

__all__ = ["AdaptiveResult", "run_adaptive", "run_fixed", "signed_buckets"]

DEFAULT_FPS = 30.0
#: fewest repeated differences ``noise="repeat"`` estimates ``σ̂`` from (the smallest block).
MIN_REPEATS = 4


@dataclass
class AdaptiveResult:
    """What a pipeline run did.

    Attributes:
        image: reconstruction ``(1, 1, n, n)`` (veil-compensated where that stage ran).
        kind: buckets used (``"gated"`` or ``"depth"``); ``polarity`` of the image.
        method: reconstructor; ``n_iter``: its iterations; ``solver_stop``: why it stopped.
        patterns_used: ±1 patterns measured (repeats included), ``patterns_max`` at max SR,
            ``repeat_patterns`` of them spent on the noise estimate.
        acquisition_stop: why acquisition stopped.
        skipped: stages skipped, each with the reason; ``stages``: stages that ran.
        veil, far: the detector outputs (``far.significance`` NaN: no noise level, the
            far-background test not made); ``noise_sigma``: ``σ̂`` of the buckets used.
        acquisition_s, compute_s: frame time at ``fps`` and measured compute time.
        fixed: the fixed pipeline's result to compare with (``time_saved_s``).
    """

    image: torch.Tensor
    kind: str
    polarity: str
    method: str
    n_iter: int
    solver_stop: str
    patterns_used: int
    patterns_max: int
    repeat_patterns: int
    acquisition_stop: str
    skipped: list[str] = field(default_factory=list)
    stages: list[str] = field(default_factory=list)
    veil: VeilEstimate | None = None
    far: FarEstimate | None = None
    noise_sigma: float | None = None
    acquisition_s: float = 0.0
    compute_s: float = 0.0
    choice: MethodChoice | None = None
    progressive: ProgressiveResult | None = None
    fixed: AdaptiveResult | None = None
    stop_kind: str = "depth"

    @property
    def total_s(self) -> float:
        return self.acquisition_s + self.compute_s

    @property
    def time_saved_s(self) -> float | None:
        """Fixed minus adaptive total time (``None`` without a fixed run)."""
        return None if self.fixed is None else self.fixed.total_s - self.total_s

    def summary(self) -> str:
        lines = [
            f"patterns {self.patterns_used}/{self.patterns_max} ({self.repeat_patterns} repeated "
            f"for the noise level): {self.acquisition_stop}",
            f"{self.method}: {self.n_iter} iterations, stopped by {self.solver_stop}",
            f"stages run: {', '.join(self.stages) or '-'}",
            f"skipped: {'; '.join(self.skipped) or '-'}",
        ]
        if self.veil is not None:
            lines.append(f"veil: {self.veil.present} (alpha^ {self.veil.alpha:.2f}, D^s "
                         f"{self.veil.ds_m:+.2f} m, dark frame shift {self.veil.shift_m:+.2f} m)")
        if self.far is not None:
            lines.append(f"far background: {self.far.present} (R = {self.far.ratio:.2f}, "
                         f"{self.far.significance:.1f} sigma)")
        t = f"time {self.total_s:.2f} s (acquisition {self.acquisition_s:.2f} s + compute " \
            f"{self.compute_s:.3f} s)"
        if self.fixed is not None:
            t += f"; fixed pipeline {self.fixed.total_s:.2f} s, saved {self.time_saved_s:.2f} s"
        lines.append(t)
        return "\n".join(lines)


def _check_data(data, fn: str) -> int:
    """``data`` an :class:`~torchtof.experiment.ExperimentData` (or a run with its fields);
    returns its number of realisations."""
    if not all(hasattr(data, a) for a in ("config", "buckets", "measurements", "operator",
                                         "hadamard")) or not isinstance(data.buckets, dict):
        raise TypeError(f"{fn}: expected data to be an ExperimentData, got "
                        f"{type(data).__name__}")
    need = ("depth", "depth_gated", "intensity")
    if not all(k in data.buckets for k in need):
        raise ValueError(f"{fn}: expected data.buckets with keys {need}, got "
                         f"{sorted(data.buckets)}")
    return int(data.buckets["depth"].shape[0])


def _check_r(r, n_real: int, fn: str) -> None:
    check_int(r, "r", fn)
    if not 0 <= r < n_real:
        raise ValueError(f"{fn}: expected r in [0, {n_real}), got {r}")


def signed_buckets(data, r: int, sr: float | None = None) -> dict[str, torch.Tensor]:
    """The signed orthonormal buckets ``(1, 1, M)`` of realisation ``r`` at ``sr`` (default:
    the largest) as :class:`ProgressiveStop` takes them.

    Raises:
        TypeError: ``data`` not an ``ExperimentData``, ``r`` not an int, ``sr`` not a number.
        ValueError: ``r`` outside ``[0, R)``, ``sr`` outside ``(0, max SR]``.
    """
    fn = "signed_buckets"
    _check_r(r, _check_data(data, fn), fn)
    top = max(data.config.srs)
    if sr is None:
        sr = top
    elif not 0.0 < check_number(sr, "sr", fn) <= top:
        raise ValueError(f"{fn}: expected sr in (0, {top}] (the run's largest SR), got {sr}")
    out = {}
    for key, kind, gate in (("depth", "depth", False), ("gated", "depth", True),
                            ("intensity", "intensity", False)):
        out[key] = data.measurements(sr, kind, gate)[1][r : r + 1]
    return out


def _raw(data, r: int) -> dict[str, torch.Tensor]:
    return {k: data.buckets[k][r : r + 1, :, :2] for k in ("depth", "depth_gated", "intensity")}


_REF_CACHE: dict = {}


def _reference(data) -> DarkReference:
    key = repr(data.config)
    if key not in _REF_CACHE:
        with cache_build():
            _REF_CACHE[key] = dark_reference(data.config)
    return _REF_CACHE[key]


def _check_alpha(veil: VeilEstimate, ref: DarkReference, fn: str) -> None:
    """Refuse the Eq. 15 compensation ``y/α̂`` with ``α̂ <= 0``: the dark frame holds no light
    (or a negative reading) against a reference that does (:func:`detect_veil`)."""
    if not veil.alpha > 0:  # (with the default alpha_max such a veil is always present)
        raise ValueError(
            f"{fn}: expected data whose dark frame keeps some of the reference's light "
            f"(alpha^ = dark-frame intensity / reference.intensity > 0, paper Eq. 15: the "
            f"image is divided by alpha^), got alpha^ = {veil.alpha} against "
            f"reference.intensity = {ref.intensity}; check the reference and the record")


def _frames_s(patterns: int, fps: float) -> float:
    return 2 * patterns / fps  # one ToF frame per DMD pattern, two patterns per ±1 row


def _check_common(data, r, method, fps, reference, fn: str) -> int:
    n_real = _check_data(data, fn)
    _check_r(r, n_real, fn)
    if method is not None and method not in SOLVERS:
        raise ValueError(f"{fn}: expected method in {SOLVERS} or None, got {method!r}")
    check_positive(fps, "fps", fn)
    if reference is not None and not isinstance(reference, DarkReference):
        raise TypeError(f"{fn}: expected reference to be a DarkReference or None, got "
                        f"{type(reference).__name__}")
    return n_real


def run_fixed(data, r: int = 0, method: str = "TVAL3", fps: float = DEFAULT_FPS,
              reference: DarkReference | None = None) -> AdaptiveResult:
    """The fixed pipeline on realisation ``r`` (module docstring).

    Raises:
        TypeError, ValueError: as :func:`run_adaptive` for ``data``, ``r``, ``method``
            (``None`` not allowed), ``fps`` and ``reference``, and a dark frame without
            light against a reference with some (``α̂ <= 0``: no Eq. 15 compensation).
    """
    _check_common(data, r, method, fps, reference, "run_fixed")
    if method is None:
        raise ValueError(f"run_fixed: expected method in {SOLVERS}, got None")
    sr = max(data.config.srs)
    t0 = time.perf_counter()
    ref = reference or _reference(data)
    veil = detect_veil(_raw(data, r), ref, data.config.roi_px**2)
    _check_alpha(veil, ref, "run_fixed")  # the fixed pipeline always compensates
    A, y = data.measurements(sr, "depth", True)
    sol = solve_at_noise(method, y[r : r + 1], A, None, sign=1.0)
    image = sol.x / veil.alpha  # Eq. 15 compensation (always run in the fixed pipeline)
    dt = time.perf_counter() - t0
    m = A.m
    return AdaptiveResult(
        image=image, kind="gated", polarity="positive", method=method, n_iter=int(sol.n_iter[0, 0]),
        solver_stop=sol.stop_reason[0][0], patterns_used=m, patterns_max=m, repeat_patterns=0,
        acquisition_stop="fixed: every pattern up to the maximum SR",
        stages=["depth gate", "veil compensation"], veil=veil,
        acquisition_s=_frames_s(m, fps), compute_s=dt)


def run_adaptive(data, r: int = 0, block: int = 32, method: str | None = None,
                 time_budget_s: float | None = None, target_psnr: float | None = None,
                 fps: float = DEFAULT_FPS, repeat: bool = True,
                 reference: DarkReference | None = None, stop: ProgressiveStop | None = None,
                 compare_fixed: bool = True, stop_kind: str = "auto",
                 gate_level: float = 0.99, disc_level: float = 0.05,
                 model_sigma: bool = True, noise: str = "pairs") -> AdaptiveResult:
    """The adaptive pipeline on realisation ``r`` of a run (module docstring).

    Args:
        data: :class:`~torchtof.experiment.ExperimentData` (a recorded or simulated run at
            the maximum SR; smaller SRs are its prefixes). With ``noise="repeat"``,
            ``repeat=True`` and more than one realisation, the repeat of the second block
            (patterns ``block`` to ``2·block − 1``, or to the end of the record if it is
            shorter) is taken from realisation ``(r + 1) mod R`` (an independent draw of the
            same patterns).
        r: realisation (an int in ``[0, R)``).
        block: patterns per block (an int ``>= 4``; with the repeats at least 4 patterns
            must follow the first block: ``block <= M − 4``, so ``M >= 8``).
        method: reconstructor, one of :data:`~torchtof.adaptive.SOLVERS` (``None``: TVAL3,
            or :func:`choose_method` with a budget; a budget is ignored when ``method`` is
            given).
        time_budget_s, target_psnr: budget for :func:`choose_method` (``time_budget_s > 0``,
            ``inf`` for no limit as there; ``target_psnr`` finite).
        fps: ToF frames per second for the acquisition time (``> 0``, finite).
        repeat: with ``noise="repeat"``, measure the second block twice for ``σ̂`` (else
            estimate it from the blocks; the far-background test, which needs a noise level,
            is then not made, and says so in ``skipped``).
        reference: clear set-up dark frame (default: simulated for ``data.config``).
        stop: a custom :class:`ProgressiveStop` for the record's ``n`` and order (it reads its
            own ``kind``). A copy runs: the caller's stop is not changed; the copy's
            ``noise_sigma``, if ``None``, is the pipeline's (``"pairs"`` or ``σ̂``).
        compare_fixed: also run :func:`run_fixed` and attach it.
        stop_kind: buckets the default stop reads: ``"auto"`` (default) the kind the gate
            test on the first 128 patterns chose; a fixed kind (``"depth"``: the ungated
            buckets whatever the gate) lets the gate be decided on all the patterns acquired.
        gate_level: level of the F test of :func:`gate_changes_image`.
        disc_level: the discrepancy stop uses ``q σ̂²``, the ``1 − disc_level`` lower
            confidence limit of ``σ²`` (:func:`~torchtof.adaptive.noise.variance_lower_factor`).
        model_sigma: also give ``σ̂`` to TVAL3's ``mu="auto"`` model choice (default: yes).
        noise: where ``σ̂`` comes from: ``"pairs"`` (default: the pair sums ``y⁺ + y⁻`` of
            all pairs measured so far, :func:`~torchtof.adaptive.noise.noise_from_pair_sums`:
            no extra patterns;
            ``τ`` from the estimator's effective degrees of freedom ``ν ≈ 0.31 (m − 2)``,
            :func:`~torchtof.adaptive.noise.pair_noise_dof`; the gate's F test takes the
            ``K = m_test − 2`` successive differences as its repeats, on their
            ``ν ≈ 0.67 K`` degrees of freedom) or ``"repeat"`` (the second block measured
            twice, with ``repeat=True``).

    Returns:
        :class:`AdaptiveResult`.

    Raises:
        TypeError: ``data`` not an ``ExperimentData``, ``reference`` not a
            :class:`DarkReference`, ``stop`` not a :class:`ProgressiveStop`, ``r`` or
            ``block`` not an int, a flag not a bool, a number that is not one.
        ValueError: ``r`` out of range, ``block < 4`` (or too large for the repeats; a
            record of fewer than 8 patterns with ``noise="repeat"`` and ``repeat=True``),
            unknown ``method``, ``stop_kind`` or ``noise``, a level outside ``(0, 1)``,
            ``fps`` or ``time_budget_s`` not ``> 0``, a NaN/Inf target, a ``stop`` for another
            ``n`` or order. All checked before any work. Then, from the data: a dark frame
            without light against a reference with some (``α̂ <= 0``, no Eq. 15
            compensation), raised after the veil detection, before the reconstruction.
    """
    fn = "run_adaptive"
    n_real = _check_common(data, r, method, fps, reference, fn)
    cfg = data.config
    block = check_int(block, "block", fn, lo=4)
    if time_budget_s is not None:
        if isinstance(time_budget_s, bool) or not isinstance(time_budget_s, (int, float)):
            raise TypeError(f"{fn}: expected time_budget_s to be a number or None, got "
                            f"{type(time_budget_s).__name__}")
        if not time_budget_s > 0:  # NaN too
            raise ValueError(f"{fn}: expected time_budget_s > 0, got {time_budget_s}")
    if target_psnr is not None:
        check_number(target_psnr, "target_psnr", fn)
    for name, v in (("repeat", repeat), ("compare_fixed", compare_fixed),
                    ("model_sigma", model_sigma)):
        check_bool(v, name, fn)
    if stop is not None:
        if not isinstance(stop, ProgressiveStop):
            raise TypeError(f"{fn}: expected stop to be a ProgressiveStop or None, got "
                            f"{type(stop).__name__}")
        if stop.n != cfg.n or stop.order != cfg.order:
            raise ValueError(f"{fn}: expected a stop for the record's n = {cfg.n} and order "
                             f"{cfg.order!r}, got n = {stop.n}, order {stop.order!r}")
    if stop_kind not in ("auto", "depth", "gated", "intensity"):
        raise ValueError(f"run_adaptive: expected stop_kind in ('auto', 'depth', 'gated', "
                         f"'intensity'), got {stop_kind!r}")
    if noise not in ("repeat", "pairs"):
        raise ValueError(f"run_adaptive: expected noise in ('repeat', 'pairs'), got {noise!r}")
    for name, v in (("gate_level", gate_level), ("disc_level", disc_level)):
        if not 0.0 < check_number(v, name, fn) < 1.0:
            raise ValueError(f"run_adaptive: expected {name} in (0, 1), got {v!r}")
    pairs = noise == "pairs"
    rep = (r + 1) % n_real if (repeat and n_real > 1 and not pairs) else None
    big_m = data.hadamard.m
    rep_end = min(2 * block, big_m)  # the second block, cut by the end of the record
    n_rep = max(rep_end - block, 0) if rep is not None else 0  # repeated patterns measured
    if rep is not None and n_rep < MIN_REPEATS:
        if big_m < 2 * MIN_REPEATS:  # no block >= 4 leaves 4 patterns to repeat
            raise ValueError(f"{fn}: expected a record of at least {2 * MIN_REPEATS} patterns "
                             f"for noise='repeat' (a first block of >= {MIN_REPEATS} and "
                             f">= {MIN_REPEATS} repeats of the second), got {big_m}; use "
                             f"noise='pairs' or repeat=False")
        raise ValueError(f"{fn}: noise='repeat' measures the second block (patterns block "
                         f"to 2*block - 1) twice, but with block={block} and {big_m} patterns "
                         f"{n_rep} are left to repeat; expected block <= {big_m - MIN_REPEATS} "
                         f"(at least {MIN_REPEATS} repeats), or repeat=False")
    sr = max(cfg.srs)
    # scipy.stats (the F quantile of the gate test, the χ² one of the discrepancy bound) is
    # imported lazily by both: import it before the clock starts, so that a first call's
    # compute_s does not hold the import (~0.5 s)
    import scipy.stats  # noqa: F401

    t0 = time.perf_counter()
    ref = reference or _reference(data)
    raw = _raw(data, r)
    veil = detect_veil(raw, ref, cfg.roi_px**2)
    _check_alpha(veil, ref, fn)
    sb = signed_buckets(data, r, sr)
    # noise of the second block: repeated (independent realisation) or from the blocks
    sb_rep = signed_buckets(data, rep, sr) if rep is not None else None
    stop_pairs = stop is not None and isinstance(stop.noise_sigma, str)
    if pairs or stop_pairs:  # the pair sums (y⁺ + y⁻)/n of every kind, read as "<kind>_sum"
        n_pat = sb["depth"].shape[-1]
        for k, key in (("depth", "depth"), ("gated", "depth_gated"), ("intensity", "intensity")):
            sb[f"{k}_sum"] = pair_sums(data.buckets[key][r : r + 1, :, : 2 * n_pat], cfg.n)

    def sigma_of(kind, m_est=None):
        if pairs:
            return float(noise_from_pair_sums(sb[f"{kind}_sum"][..., : m_est or 2 * block]))
        if sb_rep is None:
            return None
        d = sb[kind][..., block:rep_end] - sb_rep[kind][..., block:rep_end]
        return float((d.pow(2).sum() / (2 * n_rep)).sqrt())

    skipped, stages = [], []
    sigma_i = sigma_of("intensity")
    if sigma_i is None:  # no noise level: |ΔS| cannot be judged significant, no test
        far = detect_far_background(raw, None)
        skipped.append("far-background test (no noise level: noise='repeat' without a "
                       "repeated block)")
    else:  # (σ̂ = 0 exactly, noise-free buckets: any change is significant)
        far = detect_far_background(raw, (sigma_i or 1e-12) * cfg.n)
    auto = stop is None and stop_kind == "auto"
    gate_test = None

    def test_gate(m_test):  # does the gate change the image of the first m_test patterns?
        if pairs:  # successive differences of the pair sums stand in for repeats (var 2σ²)
            d = {k: pair_differences(sb[f"{k}_sum"][..., :m_test]) for k in ("depth", "gated")}
            # correlated differences (lag-one −1/2): their mean square has ν ≈ 0.67 K dof
            g_dof = pair_noise_dof(d["depth"].shape[-1], robust=False)
        else:
            d = {k: sb[k][..., block:rep_end] - sb_rep[k][..., block:rep_end]
                 for k in ("depth", "gated")}
            g_dof = None
        return gate_changes_image(sb["depth"][..., :m_test], sb["gated"][..., :m_test],
                                  d["depth"], d["gated"], level=gate_level, dof=g_dof)

    has_noise = pairs or sb_rep is not None
    # the F test needs GATE_MIN_BUCKETS coefficients: a shorter record keeps the gate untested
    too_short = big_m < GATE_MIN_BUCKETS
    if too_short and has_noise:
        skipped.append(f"gate test (only {big_m} patterns: its F test needs >= "
                       f"{GATE_MIN_BUCKETS})")
    if auto and has_noise and not too_short:  # decided before the stop, which reads the kind
        gate_test = test_gate(min(max(2 * block, 128), sb["depth"].shape[-1]))
    early_gate = veil.present or far.present or gate_test is None or gate_test.present
    s_kind = (("gated" if early_gate else "depth") if auto else
              stop_kind if stop is None else stop.kind)
    s_sigma = "pairs" if pairs else sigma_of(s_kind)
    if stop is None:
        stopper = ProgressiveStop(cfg.n, block=block, noise_sigma=s_sigma, order=cfg.order,
                                  kind=s_kind)
    else:  # the caller's stop is left as it is: a copy, reset, runs
        stopper = copy.copy(stop)
        stopper.reset()
        if stopper.noise_sigma is None:
            stopper.noise_sigma = s_sigma
    prog = run_progressive(sb, stopper)
    m = prog.m
    if not auto and has_noise and not too_short:  # the stop did not depend on it: all m
        gate_test = test_gate(m)
    gate = veil.present or far.present or (gate_test is None or gate_test.present)
    if gate:
        why = ("veil" if veil.present else "far background" if far.present else
               "too few patterns to test it" if gate_test is None and has_noise else
               "no repeat to test it" if gate_test is None else
               f"it changes the image: rho {gate_test.rho:.2f}")
        stages.append(f"depth gate ({why})")
    else:
        skipped.append(f"depth gate (no veil, no far background, the gate does not change "
                       f"the image: rho {gate_test.rho:.2f})")
    kind = "gated" if gate else "depth"
    if veil.present:
        stages.append(f"veil compensation (alpha^ {veil.alpha:.2f})")
    else:
        skipped.append("veil compensation (no veil)")
    sigma = sigma_of(kind, m)
    # 4. Morozov's bound at the lower confidence limit of σ̂² (χ² with B degrees of freedom):
    # an over-estimated σ̂ would stop the solver before it fits the signal
    # pairs: K = m − 2 differences (the all-on pair skipped), MAD: ν ≈ 0.31 K (pair_noise_dof)
    dof = pair_noise_dof(m - 2) if pairs else n_rep
    tau = variance_lower_factor(dof, disc_level) if sigma is not None else 1.0
    choice = None
    if method is None:
        if time_budget_s is not None or target_psnr is not None:
            choice = choose_method(cfg.n, m / cfg.n**2, time_budget_s=time_budget_s,
                                   target_psnr=target_psnr)
            method = choice.method
        else:
            method = "TVAL3"
    A = data.operator(m / cfg.n**2)
    sign = 1.0 if gate else -1.0
    n_iter = choice.n_iter if choice is not None else None
    sol = solve_at_noise(method, sb[kind][..., :m], A, sigma, max_iter=n_iter, sign=sign, tau=tau,
                         model_sigma=model_sigma)
    image = sol.x / veil.alpha if veil.present else sol.x
    dt = time.perf_counter() - t0
    res = AdaptiveResult(
        image=image, kind=kind, polarity="positive" if gate else "negative", method=method,
        n_iter=int(sol.n_iter[0, 0]), solver_stop=sol.stop_reason[0][0], patterns_used=m + n_rep,
        patterns_max=data.hadamard.m, repeat_patterns=n_rep, acquisition_stop=prog.reason,
        skipped=skipped, stages=stages, veil=veil, far=far, noise_sigma=sigma,
        acquisition_s=_frames_s(m + n_rep, fps), compute_s=dt, choice=choice, progressive=prog,
        stop_kind=stopper.kind)
    if compare_fixed:
        res.fixed = run_fixed(data, r, method="TVAL3", fps=fps, reference=ref)
    return res
