"""Why the specular component (diagnostic, reporting only; nothing here selects a checkpoint or a setting):

1. the detail-ratio exponent (isettorch.metrics.image_statistics.detail_ratio_exponent) of scikit-image's four colour
   photographs (as stored, sRGB-encoded, and decoded to linear) and of the held-out synthetic sets v5 and spec1
   (80 % of their scenes are encoded, ``make_heldout.py --domain mixed``; a ratio world reads 1 in either encoding);
2. where the shipped network loses to Menon 2007 on those photographs: per-channel MSE and its luminance / chroma
   split (crop 10).

    python training/runs/specular_2026-11-27/diagnosis.py [--net out/.../best.pt ...]
"""
import argparse
import glob
import json
import sys

import numpy as np
import torch
from skimage import io

sys.path.insert(0, ".")
from benchmarks.demosaic_package_photos import package_photos  # noqa: E402
from isettorch.image import srgb_decode  # noqa: E402
from isettorch.isp.evaluation import _demosaic_call, cpsnr, load_demosaic_model, mosaic  # noqa: E402
from isettorch.metrics.image_statistics import detail_ratio_exponent  # noqa: E402


def as_tensor(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(a[..., :3].astype(np.float64) / 255).permute(2, 0, 1)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--net", nargs="*", default=["out/train_demosaic_noise_free_distill4/best.pt"])
    ap.add_argument("--out", default="training/runs/specular_2026-11-27/diagnosis.json")
    args = ap.parse_args()
    torch.set_num_threads(2)
    photos = package_photos()
    res = {"detail_ratio_exponent": {}, "errors": {}}
    ims = [as_tensor(a) for _, a in photos]
    res["detail_ratio_exponent"]["skimage4 encoded"] = detail_ratio_exponent(ims)
    res["detail_ratio_exponent"]["skimage4 linear"] = detail_ratio_exponent([srgb_decode(i) for i in ims])
    for d in ("out/heldout_v5", "out/heldout_spec1"):
        res["detail_ratio_exponent"][d] = detail_ratio_exponent(
            [as_tensor(io.imread(f)) for f in sorted(glob.glob(d + "/*.png"))])
    for k, v in res["detail_ratio_exponent"].items():
        print(f"{k}: exponent {v[0]:.2f} ({v[1]} windows)")
    methods = {"menon2007": ("menon2007", None)} | {p: ("model", load_demosaic_model(p)) for p in args.net}
    c = 10
    for name, a in photos:
        truth = as_tensor(a)[None]
        raw = mosaic(truth, "RGGB").float()
        for m, (method, model) in methods.items():
            call = _demosaic_call(method, model, "RGGB", 0.0, 0.0, torch.device("cpu"), torch.float32, {})
            with torch.no_grad():
                est = call(raw).double().clamp(0, 1)
            e = (est - truth)[0, :, c:-c, c:-c]
            lum = e.mean(0)
            row = {"cpsnr": cpsnr(est, truth, c)[0].item(),
                   "mse_rgb": [float(x) for x in (e ** 2).mean((1, 2))],
                   "mse_luminance_share": float(3 * (lum ** 2).mean() / (e ** 2).sum(0).mean())}
            res["errors"].setdefault(name, {})[m] = row
            print(name, m, f"cpsnr {row['cpsnr']:.2f}", "mse R G B", " ".join(f"{x:.2e}" for x in row["mse_rgb"]),
                  f"luminance share {row['mse_luminance_share']:.2f}")
    with open(args.out, "w") as f:
        json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
