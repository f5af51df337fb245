"""Kodak and McMaster CPSNR (crop 10, RGGB, float32) of the shipped stage 3 and of the relative-grain run, per image,
scored after the screen's decision, for reporting only (no checkpoint or setting is chosen on them)."""
import json
import os

import torch

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model

if __name__ == "__main__":
    torch.set_num_threads(2)
    root = os.environ["ISETTORCH_DATA"]
    res = {}
    for name, path in {"stage3": "out/train_demosaic_noise_free_stage3/best.pt",
                       "relgrain": "out/train_demosaic_noise_free_relgrain/best.pt"}.items():
        net = load_demosaic_model(path)
        for bench in ("kodak24", "mcmaster18"):
            r = evaluate_demosaic(f"{root}/{bench}", model=net, crop=10)
            res.setdefault(name, {})[bench] = {"mean": r["mean_cpsnr"],
                                               "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
            print(name, bench, round(r["mean_cpsnr"], 3))
    for bench in ("kodak24", "mcmaster18"):
        for m in ("malvar2004", "menon2007"):
            r = evaluate_demosaic(f"{root}/{bench}", method=m, crop=10)
            res.setdefault(m, {})[bench] = {"mean": r["mean_cpsnr"],
                                            "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
    json.dump(res, open("training/runs/relgrain_2026-11-26/photos_reporting.json", "w"), indent=1)
