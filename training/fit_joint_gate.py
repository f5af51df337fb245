"""Choose the joint demosaic network's low-noise gate (``isettorch.isp.learned.PRETRAINED_GATES``) on held-out
synthetic scenes (``training/make_heldout.py`` sets; never Kodak/McMaster).

For each set and noise level (``var = a x + sigma^2`` on the [0, 1] mosaic, the ``demosaic-eval`` noise, seed 0), the
guarded noise-free and the guarded joint networks (the joint one without its gate) run once; each candidate
``sigma_max`` blends them with :func:`isettorch.isp.learned.level_gate_weight` and is scored (CPSNR, crop 10). The
rule, pre-registered in ``docs/training_log.md#joint_gate_2026-11-28``: the ``sigma_max`` with the highest mean over
the sets and levels ships if that mean beats the bare joint network's and no level's mean over the sets is more than
0.02 dB below it.

    python training/fit_joint_gate.py --sets out/heldout_v5 out/heldout_stress [--out gate.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from isettorch.isp import learned  # noqa: E402
from isettorch.isp.demosaicing import mosaic  # noqa: E402
from isettorch.isp.evaluation import cpsnr, load_images, noisy_mosaic  # noqa: E402

LEVELS = (("sigma", 0.0025), ("sigma", 0.005), ("sigma", 0.01), ("sigma", 0.02), ("shot", 0.001), ("shot", 0.01))
GRID = (0.005, 0.0075, 0.01, 0.0125, 0.015, 0.02)
TOLERANCE_DB = 0.02


def scores(folder, levels=LEVELS, grid=GRID) -> dict:
    """``{"<kind> <value>": {"none": dB, "<sigma_max>": dB, ...}}``: mean CPSNR of the bare joint network ("none")
    and of each gate on the images of ``folder``."""
    expert = learned.load_pretrained("noise_free")
    joint = learned.load_pretrained("joint_denoise")
    saved, joint.level_gate = joint.level_gate, None  # the guarded joint network alone; blended below
    out = {}
    try:
        items = load_images(folder)
        for kind, v in levels:
            sigma, shot = (v, 0.0) if kind == "sigma" else (0.0, v)
            feats = learned.noise_features(shot, sigma**2).float()
            per = {"none": []} | {str(m): [] for m in grid}
            for i, (_, arr) in enumerate(items):
                truth = torch.from_numpy(arr.astype(np.float64) / 255.0).permute(2, 0, 1)[None]
                raw = noisy_mosaic(mosaic(truth, "RGGB"), sigma, shot, seed=0, index=i).float()
                with torch.no_grad():
                    a = learned.demosaic_learned(raw, "RGGB", model=expert).double()
                    b = learned.demosaic_learned(raw, "RGGB", model=joint, noise=feats).double()
                per["none"].append(cpsnr(b.clamp(0, 1), truth, 10)[0].item())
                for m in grid:
                    w = learned.level_gate_weight(raw, feats, m).reshape(-1, 1, 1, 1)
                    per[str(m)].append(cpsnr((w * a + (1 - w) * b).clamp(0, 1), truth, 10)[0].item())
            out[f"{kind} {v:g}"] = {k: float(np.mean(s)) for k, s in per.items()}
    finally:
        joint.level_gate = saved
    return out


def choose(by_set: dict, grid=GRID, tolerance_db: float = TOLERANCE_DB) -> dict:
    """The pre-registered rule on ``{set: scores(set)}``: per level the mean over the sets of each gate's gain over
    the bare joint network; the best mean gain's ``sigma_max``, and whether it ships."""
    sets = list(by_set)
    levels = list(by_set[sets[0]])
    gain = {str(m): {lv: float(np.mean([by_set[s][lv][str(m)] - by_set[s][lv]["none"] for s in sets]))
                     for lv in levels} for m in grid}
    mean = {m: float(np.mean(list(g.values()))) for m, g in gain.items()}
    best = max(mean, key=mean.get)
    ships = mean[best] > 0 and min(gain[best].values()) >= -tolerance_db
    return {"gain_db": gain, "mean_gain_db": mean, "sigma_max": float(best), "ships": bool(ships)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sets", nargs="+", required=True, help="held-out synthetic image folders")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", default=None, help="write the scores and the decision (JSON) here")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    by_set = {s: scores(s) for s in args.sets}
    decision = choose(by_set)
    for m, g in decision["gain_db"].items():
        print(f"sigma_max {m}: " + " ".join(f"{lv} {d:+.3f}" for lv, d in g.items())
              + f" | mean {decision['mean_gain_db'][m]:+.3f}")
    print(f"chosen sigma_max {decision['sigma_max']:g}, ships: {decision['ships']}")
    if args.out:
        Path(args.out).write_text(json.dumps({"scores": by_set, **decision}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
