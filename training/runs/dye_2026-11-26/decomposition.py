"""Which part of the stress sets costs the networks: saturation (channel gains 1, 0.15, 0.15) alone, grain (std 0.005)
alone, both (the stress set), on the same 24 held-out v5 scenes. Diagnostic, not a selection."""
import json

import torch

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model

torch.set_num_threads(2)
sets = {"v5": "out/heldout_v5", "v5 gains only": "out/heldout_v5_sat", "v5 grain only": "out/heldout_v5_grain",
        "v5 stress (both)": "out/heldout_v5_stress"}
nets = {k: load_demosaic_model(f"out/train_demosaic_noise_free_{k}/best.pt") for k in ("stage3", "stage5", "dye")}
res = {}
for name, s in sets.items():
    row = {m: evaluate_demosaic(s, m, "RGGB", 10)["mean_cpsnr"] for m in ("malvar2004", "menon2007")}
    row.update({k: evaluate_demosaic(s, "learned", "RGGB", 10, model=n)["mean_cpsnr"] for k, n in nets.items()})
    res[name] = row
    print(f"{name:18s} " + " ".join(f"{k} {v:.2f}" for k, v in row.items()), flush=True)
json.dump(res, open("training/runs/dye_2026-11-26/decomposition.json", "w"), indent=1)
