"""Kodak and McMaster CPSNR (crop 10, RGGB, float32) of stage 3 and of the distilled student, one pass and with the
transpose self-ensemble, per image, scored after the screen's decision, for reporting only (no checkpoint or setting
is chosen on them).

    ISETTORCH_DATA=... python training/runs/distill_2026-11-27/photos_reporting.py
"""
import json
import os

import torch

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model

NETS = {"stage3": "out/train_demosaic_noise_free_stage3/best.pt",
        "distill": "out/train_demosaic_noise_free_distill/best.pt"}

if __name__ == "__main__":
    torch.set_num_threads(2)
    root = os.environ["ISETTORCH_DATA"]
    res = {}
    for name, path in NETS.items():
        net = load_demosaic_model(path)
        for ens in (False, True):
            key = name + (" + self-ensemble" if ens else "")
            for bench in ("kodak24", "mcmaster18"):
                r = evaluate_demosaic(f"{root}/{bench}", model=net, crop=10, self_ensemble=ens)
                res.setdefault(key, {})[bench] = {"mean": r["mean_cpsnr"],
                                                  "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
                print(key, bench, round(r["mean_cpsnr"], 3), flush=True)
    json.dump(res, open("training/runs/distill_2026-11-27/photos_reporting.json", "w"), indent=1)
