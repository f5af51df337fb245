"""Kodak, McMaster and scikit-image's four colour photographs (CPSNR, crop 10, RGGB, float32) of the shipped
distill-4 and of the specular run, per image, scored after the screen's decision, for reporting only (no checkpoint
or setting is chosen on them).

    ISETTORCH_DATA=/path/to/data python training/runs/specular_2026-11-27/photos_reporting.py
    (the specmix run: ... --nets specmix=out/train_demosaic_noise_free_specmix/best.pt --no-classical
    --out training/runs/specmix_2026-11-27/photos_reporting.json)
"""
import argparse
import json
import os
import sys

import torch

sys.path.insert(0, ".")
from benchmarks.demosaic_package_photos import package_photos  # noqa: E402
from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model  # noqa: E402

NETS = {"distill4": "out/train_demosaic_noise_free_distill4/best.pt",
        "specular": "out/train_demosaic_noise_free_specular/best.pt"}

if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--nets", nargs="*", default=[f"{k}={v}" for k, v in NETS.items()], help="name=checkpoint")
    ap.add_argument("--no-classical", action="store_true")
    ap.add_argument("--out", default="training/runs/specular_2026-11-27/photos_reporting.json")
    args = ap.parse_args()
    nets = dict(spec.split("=", 1) for spec in args.nets)
    torch.set_num_threads(2)
    root = os.environ["ISETTORCH_DATA"]
    sets = {"kodak24": f"{root}/kodak24", "mcmaster18": f"{root}/mcmaster18", "skimage4": package_photos()}
    res = {}
    for name, path in nets.items():
        net = load_demosaic_model(path)
        for bench, images in sets.items():
            r = evaluate_demosaic(images, model=net, crop=10)
            res.setdefault(name, {})[bench] = {"mean": r["mean_cpsnr"],
                                               "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
            print(name, bench, round(r["mean_cpsnr"], 3), flush=True)
    for m in () if args.no_classical else ("malvar2004", "menon2007"):
        for bench, images in sets.items():
            r = evaluate_demosaic(images, method=m, crop=10)
            res.setdefault(m, {})[bench] = {"mean": r["mean_cpsnr"],
                                            "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
            print(m, bench, round(r["mean_cpsnr"], 3), flush=True)
    with open(args.out, "w") as f:
        json.dump(res, f, indent=1)
