"""``isettorch demosaic-eval DIR --method NAME``: CPSNR of a demosaic method on a folder of 8-bit images, with the
benchmark convention of shared/data/README.md (ground truth = image / 255 as linear; noise-free mosaic; output
clipped to [0, 1]; CPSNR over the three channels, averaged over images; ``--crop`` excludes a border)."""

from __future__ import annotations

import json
import math


def register(sub) -> None:
    p = sub.add_parser("demosaic-eval", help="score a demosaic method (CPSNR, ms/image) on a folder of 8-bit images")
    p.add_argument("folder", metavar="DIR", help="folder of 8-bit RGB .png/.tif images")
    p.add_argument("--method", default="bilinear",
                   help="nearest, bilinear, bilinear_colour (colour-demosaicing border), malvar2004, menon2007, or a "
                        "registered method such as learned")
    p.add_argument("--pattern", default="RGGB", help="Bayer pattern of the simulated mosaic (default RGGB)")
    p.add_argument("--crop", type=int, default=0, help="border excluded from the score, pixels (default 0)")
    p.add_argument("--dtype", choices=("float32", "float64"), default="float64", help="compute dtype")
    p.add_argument("--device", default="cpu", help="torch device (default cpu)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(func=run)


def _finite_or_none(x: float):
    return x if math.isfinite(x) else None


def run(args) -> int:
    import torch

    from ..isp.evaluation import evaluate_demosaic

    if args.threads is not None:
        torch.set_num_threads(args.threads)
    res = evaluate_demosaic(args.folder, args.method, args.pattern.upper(), args.crop,
                            dtype=getattr(torch, args.dtype), device=args.device)
    if args.json:
        res["mean_cpsnr"] = _finite_or_none(res["mean_cpsnr"])
        for item in res["images"]:
            item["cpsnr"] = _finite_or_none(item["cpsnr"])
        print(json.dumps(res, indent=2))
        return 0
    print(f"method {res['method']}  pattern {res['pattern']}  crop {res['crop']}  ({args.dtype}, {args.device})")
    for item in res["images"]:
        print(f"  {item['name']:<24s} {item['cpsnr']:8.3f} dB  {item['ms']:8.1f} ms")
    print(f"mean CPSNR {res['mean_cpsnr']:.3f} dB over {len(res['images'])} images, {res['ms_per_image']:.1f} ms/image")
    return 0
