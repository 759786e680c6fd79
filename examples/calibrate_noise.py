"""How the experiment's stray-light level was calibrated to the paper's raw ToF PSNR (5.70 dB).

Sweeps ``stray_e`` (pattern-independent returns, see ``torchtof.experiment.stray_light``) and
prints the raw ToF image's PSNR and the pseudo-inverse PSNR at the paper's SRs, with and
without the gate. The default (1000 e⁻) is the level past which the reconstructions stop
rising with SR (the sensor's non-linearity starts to leak the stray light into the buckets).

    python examples/calibrate_noise.py [--stray 0 500 1000 1600] [--realisations 2]
"""

import argparse

import torch

from torchtof.experiment import PaperExperiment
from torchtof.methods import evaluate, raw_tof_scores

SRS = (0.0625, 0.125, 0.25, 0.375)


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--stray", type=float, nargs="*", default=[0.0, 500.0, 1000.0, 1600.0])
    p.add_argument("--realisations", type=int, default=2)
    p.add_argument("--n", type=int, default=32)
    args = p.parse_args(argv)
    out = []
    for stray in args.stray:
        data = PaperExperiment(sr=max(SRS), stray_e=stray, n=args.n, roi_px=2 * args.n,
                               srs=SRS).run(seed=0, realisations=args.realisations)
        raw = raw_tof_scores(data)
        row = {"stray_e": stray, "raw_psnr": raw["psnr"], "raw_std": raw["psnr_std"]}
        for gate in (False, True):
            row["pinv_gate" if gate else "pinv"] = [
                round(evaluate(data, sr, gate, ("PINV",))[0][0]["psnr"], 2) for sr in SRS]
        out.append(row)
        print(f"stray {stray:6.0f} e-: raw ToF {raw['psnr']:.2f} ± {raw['psnr_std']:.2f} dB; "
              f"PINV at SR {[f'{s:.2%}' for s in SRS]}: no gate {row['pinv']}, "
              f"gate {row['pinv_gate']}", flush=True)
    return out


if __name__ == "__main__":
    torch.set_num_threads(1)
    main()
