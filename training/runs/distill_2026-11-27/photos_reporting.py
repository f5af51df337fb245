"""Kodak and McMaster CPSNR (crop 10, RGGB, float32) of stage 3 and of the distilled student, one pass and with the
transpose self-ensemble, per image, scored after the screen's decision, for reporting only (no checkpoint or setting
is chosen on them).

    ISETTORCH_DATA=... python training/runs/distill_2026-11-27/photos_reporting.py
    ISETTORCH_DATA=... python training/runs/distill_2026-11-27/photos_reporting.py \
        --nets distill=out/train_demosaic_noise_free_distill/best.pt \
        distill2=out/train_demosaic_noise_free_distill2/best.pt \
        --out training/runs/distill2_2026-11-27/photos_reporting.json
"""
import argparse
import json
import os

import torch

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model

NETS = {"stage3": "out/train_demosaic_noise_free_stage3/best.pt",
        "distill": "out/train_demosaic_noise_free_distill/best.pt"}

if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--nets", nargs="*", default=[f"{k}={v}" for k, v in NETS.items()], help="name=checkpoint pairs")
    ap.add_argument("--out", default="training/runs/distill_2026-11-27/photos_reporting.json")
    args = ap.parse_args()
    torch.set_num_threads(2)
    root = os.environ["ISETTORCH_DATA"]
    res = {}
    for name, path in (n.split("=", 1) for n in args.nets):
        net = load_demosaic_model(path)
        for ens in (False, True):
            key = name + (" + self-ensemble" if ens else "")
            for bench in ("kodak24", "mcmaster18"):
                r = evaluate_demosaic(f"{root}/{bench}", model=net, crop=10, self_ensemble=ens)
                res.setdefault(key, {})[bench] = {"mean": r["mean_cpsnr"],
                                                  "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
                print(key, bench, round(r["mean_cpsnr"], 3), flush=True)
    json.dump(res, open(args.out, "w"), indent=1)
