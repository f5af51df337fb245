"""Demosaic benchmark: CPSNR (Kodak24, McMaster18; crop 0 and 10) and ms/image for every method, and the same
scores for colour-demosaicing on the same mosaics. Convention: shared/data/README.md. Writes JSON to stdout.
Times are medians over the images of one call each, after a warm-up call (``evaluate_demosaic``'s, and one on the
first image for colour-demosaicing; it had none and its mean included the first call's imports and caches).

    python benchmarks/demosaic_bench.py [--threads 1] [--no-reference]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

from isettorch.isp import evaluate_demosaic
from isettorch.isp.evaluation import load_images

DATA = Path(os.environ.get("ISETTORCH_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data"))
SETS = {"kodak24": "Kodak", "mcmaster18": "McM"}


def reference_scores(images, name, crops):
    """colour-demosaicing 0.2 on the same noise-free mosaics, scored the same way (numpy)."""
    import colour_demosaicing as cd

    fn = {"bilinear_colour": cd.demosaicing_CFA_Bayer_bilinear, "malvar2004": cd.demosaicing_CFA_Bayer_Malvar2004,
          "menon2007": cd.demosaicing_CFA_Bayer_Menon2007}[name]
    scores = {c: [] for c in crops}
    ms = []
    fn(cd.mosaicing_CFA_Bayer(images[0][1].astype(np.float64) / 255, "RGGB"), "RGGB")  # warm-up
    for _, a in images:
        truth = a.astype(np.float64) / 255
        cfa = cd.mosaicing_CFA_Bayer(truth, "RGGB")
        t0 = time.perf_counter()
        out = np.clip(fn(cfa, "RGGB"), 0, 1)
        ms.append(1e3 * (time.perf_counter() - t0))
        for c in crops:
            sl = slice(c, -c if c else None)
            scores[c].append(10 * np.log10(1 / np.mean((out[sl, sl] - truth[sl, sl]) ** 2)))
    return {c: float(np.mean(s)) for c, s in scores.items()}, float(np.median(ms))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--no-reference", action="store_true")
    ap.add_argument("--methods", default="nearest,bilinear,bilinear_colour,malvar2004,menon2007")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    rows = []
    for folder, label in SETS.items():
        images = load_images(DATA / folder)
        for m in args.methods.split(","):
            method = m
            row = {"set": label, "method": m}
            for crop in (0, 10):
                r = evaluate_demosaic(images, method, "RGGB", crop, dtype=torch.float64)
                row[f"crop{crop}"] = r["mean_cpsnr"]
            row["ms_float64"] = float(np.median([im["ms"] for im in r["images"]]))
            r32 = evaluate_demosaic(images[:6], method, "RGGB", 0, dtype=torch.float32)
            row["ms_float32"] = float(np.median([im["ms"] for im in r32["images"]]))
            if not args.no_reference and m in ("bilinear_colour", "malvar2004", "menon2007"):
                ref, ms = reference_scores(images, m, (0, 10))
                row.update({"ref_crop0": ref[0], "ref_crop10": ref[10], "ref_ms": ms})
            rows.append(row)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
