"""Depth-resolved CGI (beyond the paper): a real depth map of a 3-D scene at DMD resolution.

The four correlation taps are linear in the light, so the per-tap buckets
C_{k,i} = Σ_p c_{k,i}(p) obey y_k = A x_k. ``torchtof.recon.DepthResolved`` turns them into
I/Q buckets (I = C₁ − C₂, Q = C₄ − C₃, Fig. 1 tap order), reconstructs the I/Q images with
any reconstructor and applies Eq. 7 (phase), Eq. 8 (amplitude) and Eq. 1 (depth) per DMD
pixel. ``JointTV`` reconstructs I and Q together with a vectorial TV (shared edges). The
differential y⁺ − y⁻ removes ambient light and stray returns, which no single ToF frame can.

    python examples/depth_resolved_cgi.py [--scene motorcycle] [--sr 0.25] [--out out]
"""

from pathlib import Path

from torchtof.apps.args import OneLineParser, sampling_rate, scene
from torchtof.experiment import PaperExperiment
from torchtof.metrics import depth_rmse
from torchtof.recon import DepthResolved, JointTV, PseudoInverse


def main(argv=None) -> dict:
    p = OneLineParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", type=scene, default="motorcycle")
    p.add_argument("--sr", type=sampling_rate, default=0.25)
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    exp = PaperExperiment(sr=args.sr, scene=args.scene, srs=(args.sr,))
    data = exp.run(seed=0, realisations=1)
    A, y = data.measurements(args.sr, kind="taps")  # (R, 4, M) per-tap buckets
    freq = data.config.freq_hz
    truth, obj = data.depth_m, data.x > 0
    res = {
        "pinv": DepthResolved(PseudoInverse(A), freq).solve(y),
        "separate": DepthResolved(JointTV(A, joint=False), freq).solve(y),
        "joint": DepthResolved(JointTV(A, joint=True), freq).solve(y),
    }
    err = {"raw": float(depth_rmse(data.raw_tof_image, truth, obj)[0])}
    err.update({k: float(depth_rmse(r.depth, truth, obj)[0]) for k, r in res.items()})
    print(f"scene {args.scene!r}, SR {args.sr:.2%}: depth RMSE over the object per DMD pixel")
    print(f"  raw ToF depth map (one frame, stray light and all): {err['raw']:.3f} m")
    print(f"  I/Q pseudo-inverse:                                 {err['pinv']:.3f} m")
    print(f"  I/Q TV per image (separate):                        {err['separate']:.3f} m")
    print(f"  I/Q vectorial TV (joint):                           {err['joint']:.3f} m")
    print(f"  amplitude mask keeps {float(res['joint'].mask.float().mean()):.0%} of the pixels")
    if args.out:
        from torchtof.apps.depth_demo import plot_depth_maps

        maps = {"raw ToF": data.raw_tof_image, **{k: r.depth for k, r in res.items()}}
        rows = [{"rmse_m": err[k]} for k in ("raw", "pinv", "separate", "joint")]
        png = plot_depth_maps(Path(args.out) / "depth_resolved.png", truth, maps, rows,
                         f"depth-resolved CGI, SR {args.sr:.2%}")
        print(f"wrote {png}")
    out = {f"rmse_{k}_m": v for k, v in err.items()}
    out["rmse_cgi_m"] = err["joint"]  # the depth-resolved CGI result (name kept for callers)
    return out


if __name__ == "__main__":
    main()
