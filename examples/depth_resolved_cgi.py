"""Depth-resolved CGI (DESIGN.md §5): a real depth map of a 3-D scene at DMD resolution.

The four correlation taps are linear in the light, so the per-tap buckets
C_{k,i} = Σ_p c_{k,i}(p) obey y_k = A x_k: reconstruct the four tap images x_k by any linear
reconstructor, then apply Eq. 7 (phase) and Eq. 1 (depth) per DMD pixel. The differential
y⁺ − y⁻ removes ambient light and stray returns, which no single ToF frame can.

    python examples/depth_resolved_cgi.py [--scene steps] [--sr 0.375] [--out out]
"""

import argparse
from pathlib import Path

import torch

from torchtof.experiment import PaperExperiment
from torchtof.metrics import depth_rmse
from torchtof.recon import PseudoInverse
from torchtof.sensor import phase_to_depth, tap_phase


def depth_from_taps(data, sr: float) -> torch.Tensor:
    """Depth map (R, 1, n, n) in metres from the per-tap buckets at ``sr``."""
    A, y = data.measurements(sr, kind="taps")  # (R, 4, M)
    taps = PseudoInverse(A)(y)  # (R, 4, n, n): one linear image per tap (Fig. 1 order)
    return phase_to_depth(tap_phase(taps), data.config.freq_hz)  # Eqs. 7 and 1


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default="steps")
    p.add_argument("--sr", type=float, default=0.375)
    p.add_argument("--out", default=None)
    args = p.parse_args(argv)
    exp = PaperExperiment(sr=args.sr, scene=args.scene, srs=(args.sr,))
    data = exp.run(seed=0, realisations=1)
    depth = depth_from_taps(data, args.sr)
    truth = data.depth_m
    raw = torch.nn.functional.avg_pool2d(data.raw_tof, data.config.roi_px // data.config.n)
    err_cgi = float(depth_rmse(depth, truth)[0])
    err_raw = float(depth_rmse(raw, truth)[0])
    print(f"scene {args.scene!r}, SR {args.sr:.2%}: depth RMSE per DMD pixel")
    print(f"  raw ToF depth map (one frame, stray light and all): {err_raw:.3f} m")
    print(f"  depth-resolved CGI from the four tap buckets:        {err_cgi:.3f} m")
    if args.out:
        from torchtof.cli import save_grid

        png = save_grid(Path(args.out) / "depth_resolved.png",
                        [("true depth", truth), ("raw ToF", raw), ("tap CGI", depth)],
                        title=f"depth-resolved CGI, SR {args.sr:.2%}")
        print(f"wrote {png}")
    return {"rmse_cgi_m": err_cgi, "rmse_raw_m": err_raw}


if __name__ == "__main__":
    main()
