"""The stress-set decomposition in absolute error instead of dB: per-image MSE (10^(-CPSNR/10), peak 1) of
Malvar-He-Cutler and stage 3 on the same 24 held-out v5 scenes, and the error each perturbation *adds*. A
perturbation that adds the same MSE to every method is error no demosaicker can avoid (information absent from the
mosaic); what a network adds beyond MHC's is its own excess. Diagnostic, not a selection (no test set is read)."""
import json

import numpy as np
import torch

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model

torch.set_num_threads(2)
sets = {"v5": "out/heldout_v5", "gains only": "out/heldout_v5_sat", "grain only": "out/heldout_v5_grain",
        "both (stress)": "out/heldout_v5_stress"}
net = load_demosaic_model("out/train_demosaic_noise_free_stage3/best.pt")
mse = {}
for name, s in sets.items():
    mse[name] = {}
    for m in ("malvar2004", "learned"):
        r = evaluate_demosaic(s, m, "RGGB", 10, model=net if m == "learned" else None)
        mse[name][m] = np.array([10 ** (-im["cpsnr"] / 10) for im in r["images"]])
out = {}
for name, base in (("grain only", "v5"), ("both (stress)", "gains only"), ("both (stress)", "v5")):
    add = {m: mse[name][m] - mse[base][m] for m in ("malvar2004", "learned")}
    row = {f"{m}_mean_mse_{k}": float(mse[k][m].mean()) for m in add for k in (base, name)}
    row.update({f"{m}_added_mse": float(a.mean()) for m, a in add.items()})
    row["images_where_network_adds_more"] = int((add["learned"] > add["malvar2004"]).sum())
    out[f"{base} -> {name}"] = row
    print(f"{base:10s} -> {name:14s} added MSE x1e-4: MHC {add['malvar2004'].mean() * 1e4:.2f}, "
          f"stage 3 {add['learned'].mean() * 1e4:.2f}; network adds more on "
          f"{row['images_where_network_adds_more']}/24", flush=True)
json.dump(out, open("training/runs/dye_2026-11-26/decomposition_mse.json", "w"), indent=1)
