"""Stage 4/5 screen, written at 13:30 on 2026-11-26 before any of these candidates was scored on anything but its
own training run's validation set, and before any Kodak/McMaster score:
candidates = the GPU 64x13 run (seed 5), stage 4 (GPU, deepened 64x21, seed 6) and stage 5 (CPU, 64x21, seed 4).
Ship the candidate with the highest held-out synthetic v5 mean among those that
  (a) beat the shipped stage 3 on held-out v5 (out/heldout_v5), and
  (b) have no held-out synthetic scene below MHC on v5, v5 stress and v4 stress.
If none qualifies, stage 3 stays shipped."""
import json
import sys

import torch

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model

torch.set_num_threads(2)
sets = ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress"]
paths = {"stage3": "out/train_demosaic_noise_free_stage3/best.pt",
         "gpu_64x13": "out/gpu_stage4_64x13/best.pt",
         "stage4": "out/train_demosaic_noise_free_stage4/best.pt",
         "stage5": "out/train_demosaic_noise_free_stage5/best.pt"}
only = sys.argv[1:] or list(paths)
nets = {k: load_demosaic_model(p) for k, p in paths.items() if k in only}
out = {}
for s in sets:
    res = {"malvar2004": evaluate_demosaic(s, "malvar2004", "RGGB", 10)}
    for k, n in nets.items():
        res[k] = evaluate_demosaic(s, "learned", "RGGB", 10, model=n)
    mhc = [i["cpsnr"] for i in res["malvar2004"]["images"]]
    row = {}
    for k, r in res.items():
        v = [i["cpsnr"] for i in r["images"]]
        below = sum(a < b for a, b in zip(v, mhc))
        worst = min(a - b for a, b in zip(v, mhc))
        row[k] = {"mean": r["mean_cpsnr"], "below_mhc": below, "worst_vs_mhc": worst,
                  "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
        print(f"{s:24s} {k:10s} {r['mean_cpsnr']:.2f} below MHC {below:2d} worst {worst:+.2f}", flush=True)
    out[s] = row
ok = {k: out[sets[0]][k]["mean"] for k in nets if k != "stage3"
      and out[sets[0]][k]["mean"] > out[sets[0]]["stage3"]["mean"]
      and all(out[s][k]["below_mhc"] == 0 for s in sets)}
out["decision"] = max(ok, key=ok.get) if ok else "stage3"
print("ship:", out["decision"])
json.dump(out, open("out/screen/screen5_" + "_".join(only) + ".json", "w"), indent=1)
