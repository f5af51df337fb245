"""Kodak, McMaster and scikit-image's four colour photographs (CPSNR, crop 10, RGGB, float32) of the shipped
distill-4 and of the specular run, per image, scored after the screen's decision, for reporting only (no checkpoint
or setting is chosen on them).

    ISETTORCH_DATA=/path/to/data python training/runs/specular_2026-11-27/photos_reporting.py
"""
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
    torch.set_num_threads(2)
    root = os.environ["ISETTORCH_DATA"]
    sets = {"kodak24": f"{root}/kodak24", "mcmaster18": f"{root}/mcmaster18", "skimage4": package_photos()}
    res = {}
    for name, path in NETS.items():
        net = load_demosaic_model(path)
        for bench, images in sets.items():
            r = evaluate_demosaic(images, model=net, crop=10)
            res.setdefault(name, {})[bench] = {"mean": r["mean_cpsnr"],
                                               "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
            print(name, bench, round(r["mean_cpsnr"], 3), flush=True)
    for m in ("malvar2004", "menon2007"):
        for bench, images in sets.items():
            r = evaluate_demosaic(images, method=m, crop=10)
            res.setdefault(m, {})[bench] = {"mean": r["mean_cpsnr"],
                                            "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
            print(m, bench, round(r["mean_cpsnr"], 3), flush=True)
    with open("training/runs/specular_2026-11-27/photos_reporting.json", "w") as f:
        json.dump(res, f, indent=1)
