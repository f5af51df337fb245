"""A second photo set, for reporting only: CPSNR (crop 10, RGGB, the Kodak/McMaster convention of
shared/data/README.md) of the classical and learned demosaickers on the colour photographs scikit-image ships in its
wheel (no download): astronaut (NASA), chelsea, coffee and motorcycle_left (Middlebury 2014 stereo). PNGs only:
rocket, retina and hubble are JPEGs, whose 4:2:0 chroma subsampling smooths colour and so favours a colour-ratio
prior. These are neither a training nor a selection set; they answer "do the gains hold on other photographs?".
``--folder DIR`` scores the 8-bit RGB .png/.tif/.jpg photographs of a folder instead (each cut to even height and width
the same way), e.g. the 30 selection photographs of ``training/selection_photos.py``, never used to train or select
a demosaicker.

    python benchmarks/demosaic_package_photos.py [--folder DIR] [--models name=path ...] [--threads 2] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from isettorch.isp import evaluate_demosaic
from isettorch.isp.evaluation import load_demosaic_model

PHOTOS = ("astronaut.png", "chelsea.png", "coffee.png", "motorcycle_left.png")
CLASSICAL = ("bilinear", "malvar2004", "menon2007")


def _even(a: np.ndarray) -> np.ndarray:
    """A last odd row or column dropped, as in every score recorded from this script (the learned demosaickers needed
    whole 2x2 Bayer cells until 2026-11-29; they now take any size, and the cut keeps the records comparable)."""
    return a[: a.shape[0] // 2 * 2, : a.shape[1] // 2 * 2]


def package_photos() -> list[tuple[str, np.ndarray]]:
    """(name, uint8 [H, W, 3]) for the colour photographs in scikit-image's data folder, cut to even height and
    width."""
    import skimage
    from skimage import io

    folder = Path(skimage.__file__).parent / "data"
    return [(n, _even(io.imread(folder / n)[..., :3])) for n in PHOTOS]


def folder_photos(folder) -> list[tuple[str, np.ndarray]]:
    """(name, uint8 [H, W, 3]) for every photograph of ``folder`` (:func:`isettorch.isp.evaluation.load_images`),
    cut to even height and width."""
    from isettorch.isp.evaluation import load_images

    return [(n, _even(a)) for n, a in load_images(folder)]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", nargs="*", default=[], help="name=checkpoint pairs scored beside the shipped model")
    ap.add_argument("--folder", default=None, help="score this folder's photographs instead of scikit-image's")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    models = [spec.partition("=")[::2] for spec in args.models]
    for spec, (name, path) in zip(args.models, models):
        if not name or not path:
            raise ValueError(f"--models: expected name=path, got {spec!r}")
    photos = package_photos() if args.folder is None else folder_photos(args.folder)
    names = [n for n, _ in photos]
    methods = (*CLASSICAL, "learned") if args.folder is None else (*CLASSICAL, "learned_tiny", "learned_small",
                                                                   "learned")
    rows = {m: evaluate_demosaic(photos, method=m, crop=10) for m in methods}
    for name, path in models:
        rows[name] = evaluate_demosaic(photos, model=load_demosaic_model(path), crop=10)
    res = {m: {"mean": r["mean_cpsnr"], **{i["name"]: i["cpsnr"] for i in r["images"]}} for m, r in rows.items()}
    print("| method | mean | " + " | ".join(names) + " |")
    print("|---|---|" + "---|" * len(names))
    for m, d in res.items():
        print(f"| {m} | {d['mean']:.2f} | " + " | ".join(f"{d[n]:.2f}" for n in names) + " |")
    if args.out:
        Path(args.out).write_text(json.dumps(res, indent=1))
    return res


if __name__ == "__main__":
    main()
