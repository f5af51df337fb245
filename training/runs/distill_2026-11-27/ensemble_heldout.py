"""Stage 3 one pass against its transpose self-ensemble on the four held-out synthetic sets (24 x 256 px, crop 10),
measured before the distillation run to motivate it (2026-11-26 23:08 UTC; run then as out/s30/ens_heldout.py, the
path screen_rule.py names)."""
import json

import torch

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model

if __name__ == "__main__":
    torch.set_num_threads(2)
    net = load_demosaic_model("out/train_demosaic_noise_free_stage3/best.pt")
    res = {}
    for s in ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress", "out/heldout_v5_relgrain"]:
        a = evaluate_demosaic(s, "learned", "RGGB", 10, model=net)["mean_cpsnr"]
        b = evaluate_demosaic(s, "learned", "RGGB", 10, model=net, self_ensemble=True)["mean_cpsnr"]
        res[s] = (a, b)
        print(s, f"{a:.3f} {b:.3f} {b - a:+.3f}", flush=True)
    json.dump(res, open("training/runs/distill_2026-11-27/ensemble_heldout.json", "w"), indent=1)
