"""Shipping screen for the dyed-materials run (configs/train/demosaic_noise_free_dye.yaml), written at 15:46 UTC on
2026-11-26, after the run started and before any of its checkpoints was scored (its own validation log aside), on
these sets or on Kodak/McMaster.

Incumbent: stage 3 (out/train_demosaic_noise_free_stage3/best.pt), which the weight-interpolation screen
(training/runs/soup_2026-11-26/soup_rule.py) chose over stage 5 by the rule fixed there.
Candidate: out/train_demosaic_noise_free_dye/best.pt.
Sets: out/heldout_v5, out/heldout_v5_stress, out/heldout_stress (24 x 256 px each, crop 10, RGGB); score = the mean
of the three means.
Ship the candidate if (a) its score beats the incumbent's, (b) none of its three means is more than 0.05 dB below
the incumbent's, and (c) no held-out scene is below MHC on any set. Otherwise the incumbent stays.
Kodak/McMaster are scored afterwards, for reporting only.
"""
import json

import torch

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model

torch.set_num_threads(2)
SETS = ["out/heldout_v5", "out/heldout_v5_stress", "out/heldout_stress"]
PATHS = {"stage3": "out/train_demosaic_noise_free_stage3/best.pt", "dye": "out/train_demosaic_noise_free_dye/best.pt"}

if __name__ == "__main__":
    res = {}
    mhc = {s: [i["cpsnr"] for i in evaluate_demosaic(s, "malvar2004", "RGGB", 10)["images"]] for s in SETS}
    for name, path in PATHS.items():
        net, row = load_demosaic_model(path), {}
        for s in SETS:
            r = evaluate_demosaic(s, "learned", "RGGB", 10, model=net)
            v = [i["cpsnr"] for i in r["images"]]
            row[s] = {"mean": r["mean_cpsnr"], "below_mhc": sum(a < b for a, b in zip(v, mhc[s])),
                      "worst_vs_mhc": min(a - b for a, b in zip(v, mhc[s])),
                      "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
        row["score"] = sum(row[s]["mean"] for s in SETS) / 3
        res[name] = row
        print(name, " ".join(f"{row[s]['mean']:.3f}({row[s]['below_mhc']})" for s in SETS),
              f"score {row['score']:.3f}", flush=True)
    a, b = res["dye"], res["stage3"]
    ok = (a["score"] > b["score"] and all(a[s]["mean"] >= b[s]["mean"] - 0.05 for s in SETS)
          and all(a[s]["below_mhc"] == 0 for s in SETS))
    res["decision"] = "dye" if ok else "stage3"
    print("ship:", res["decision"])
    json.dump(res, open("training/runs/dye_2026-11-26/screen_heldout.json", "w"), indent=1)
