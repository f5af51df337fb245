"""Weight-space interpolation screen ("WiSE-FT": Wortsman et al., CVPR 2022, "Robust fine-tuning of zero-shot
models"; "model soups": Wortsman et al., ICML 2022). Rule written at 15:40 UTC on 2026-11-26, before any
interpolated network was scored on anything, Kodak/McMaster included.

Why: stage 5 (fine-tuned from stage 3 deepened to 64 x 21) gained on held-out v5 but lost 0.10-0.13 dB on both
held-out stress sets; fine-tuned-vs-start interpolation is known to keep in-distribution gains while recovering
robustness under distribution shift.

Endpoints: S3d = stage 3 deepened to 64 x 21 by training/train_demosaic.init_state (new blocks' conv2 zero), with
the new blocks' conv1 copied from stage 5 (any conv1 leaves a zero-conv2 block an identity, so S3d computes exactly
stage 3; copying makes the interpolated block stage 5's block with its residual branch scaled by alpha).
Candidates: W(alpha) = (1 - alpha) S3d + alpha S5 for alpha in {0, 0.1, ..., 1.0} (alpha 0 = stage 3, alpha 1 =
stage 5, shipped), and "soup3" = (S3d + S4 + S5) / 3 with S4 = stage 4.
Score = mean of the three held-out means (out/heldout_v5, out/heldout_v5_stress, out/heldout_stress; 24 x 256 px,
crop 10, RGGB).
Ship the highest-score candidate if (a) its score beats stage 5's, (b) neither stress mean is below stage 5's, and
(c) no held-out scene is below MHC (Malvar-He-Cutler) on any of the three sets. Otherwise stage 5 stays shipped.
Kodak/McMaster are then scored for the shipped network only, for reporting.
"""
import json
import sys

import torch

sys.path.insert(0, "training")
from train_demosaic import init_state  # noqa: E402

from isettorch.isp.evaluation import evaluate_demosaic  # noqa: E402
from isettorch.isp.learned import DemosaicNet  # noqa: E402

torch.set_num_threads(2)
SETS = ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress"]


def load(p):
    return torch.load(p, map_location="cpu", weights_only=True)


def endpoints():
    s3, s4, s5 = (load(f"out/train_demosaic_noise_free_stage{i}/best.pt") for i in (3, 4, 5))
    net = DemosaicNet(**s5["net_config"])
    s3d = init_state(s3, net, "stage3")
    for k in s3d:
        if k not in s3["model"] and ".conv1." in k:
            s3d[k] = s5["model"][k].float().clone()
    return s3d, {k: v.float() for k, v in s4["model"].items()}, {k: v.float() for k, v in s5["model"].items()}, \
        s5["net_config"]


def candidates():
    s3d, s4, s5, cfg = endpoints()
    out = {f"a{a / 10:.1f}": {k: (1 - a / 10) * s3d[k] + a / 10 * s5[k] for k in s5} for a in range(11)}
    out["soup3"] = {k: (s3d[k] + s4[k] + s5[k]) / 3 for k in s5}
    return out, cfg


def net_of(state, cfg):
    net = DemosaicNet(**cfg)
    net.load_state_dict(state)
    return net.eval()


if __name__ == "__main__":
    cands, cfg = candidates()
    res = {}
    mhc = {s: [i["cpsnr"] for i in evaluate_demosaic(s, "malvar2004", "RGGB", 10)["images"]] for s in SETS}
    for name, state in cands.items():
        net = net_of(state, cfg)
        row = {}
        for s in SETS:
            r = evaluate_demosaic(s, "learned", "RGGB", 10, model=net)
            v = [i["cpsnr"] for i in r["images"]]
            row[s] = {"mean": r["mean_cpsnr"], "below_mhc": sum(a < b for a, b in zip(v, mhc[s])),
                      "worst_vs_mhc": min(a - b for a, b in zip(v, mhc[s]))}
        row["score"] = sum(row[s]["mean"] for s in SETS) / 3
        res[name] = row
        print(name, " ".join(f"{row[s]['mean']:.3f}({row[s]['below_mhc']})" for s in SETS),
              f"score {row['score']:.3f}", flush=True)
    ref = res["a1.0"]
    ok = {k: r["score"] for k, r in res.items() if r["score"] > ref["score"]
          and all(r[s]["mean"] >= ref[s]["mean"] for s in SETS[1:])
          and all(r[s]["below_mhc"] == 0 for s in SETS)}
    res["decision"] = max(ok, key=ok.get) if ok else "a1.0"
    print("ship:", res["decision"])
    json.dump(res, open("training/runs/soup_2026-11-26/soup_screen.json", "w"), indent=1)
