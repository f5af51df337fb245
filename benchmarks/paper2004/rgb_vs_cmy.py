"""ISET 2004 paper experiment: an RGB (GBRG) vs a CMY (YCMY) sensor on the Macbeth chart, with gray-world
illuminant correction in sensor space vs in XYZ, rendered to sRGB; mean CIEDE2000 per variant.

Farrell, Xiao, Catrysse & Wandell, "A simulation tool for evaluating digital camera image quality",
SPIE 5294 (2004), colour-processing example. Both sensors use ISETCam's default pixel (2.8 um, noise on,
auto exposure) behind the default f/4 lens; the CMY filters are the complements of ISETCam's RGB filters
(``isetcam_cmy``). The chart is lit by D65 and by tungsten (CIE A); the reference is always the chart under
D65 (the rendering white), so under A the error includes how well gray world discounts the illuminant.

    python benchmarks/paper2004/rgb_vs_cmy.py --out out/paper2004

Writes ``rgb_vs_cmy.png`` (the rendered charts), ``rgb_vs_cmy_delta_e.png`` (bar chart) and
``rgb_vs_cmy.json`` / ``.md`` (mean and max dE2000 per variant).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from isettorch.camera import Camera
from isettorch.isp.chart import macbeth_delta_e, patch_means
from isettorch.isp.pipeline import ImageProcessor
from isettorch.optics import DiffractionLimitedOptics
from isettorch.scene import macbeth
from isettorch.sensor import Sensor

SENSORS = {"RGB (GBRG)": ("GBRG", "isetcam_rgb"), "CMY (YCMY)": ("YCMY", "isetcam_cmy")}
CORRECTIONS = {"none": ("none", "xyz"), "gray world, sensor space": ("gray_world", "sensor"),
               "gray world, XYZ": ("gray_world", "xyz")}
ILLUMINANTS = ("D65", "A")


def make_camera(pattern: str, filters: str, method: str, space: str, seed: int) -> Camera:
    sensor = Sensor.preset("isetcam_default", cfa=pattern, filters=filters, rows=None, cols=None,
                           auto_exposure="luminance", seed=seed)
    isp = ImageProcessor(demosaic="bilinear", illuminant_correction=method, correction_space=space,
                         scaling="percentile", clip_negative_xyz=False)
    return Camera(DiffractionLimitedOptics(f_number=4.0), sensor, isp, noise=True)


def run(out: Path, patch_size: int = 16, seed: int = 0) -> dict:
    torch.set_num_threads(1)
    out.mkdir(parents=True, exist_ok=True)
    results, images = [], {}
    for ill in ILLUMINANTS:
        scene = macbeth(ill, patch_size=patch_size)
        for sname, (pattern, filters) in SENSORS.items():
            for cname, (method, space) in CORRECTIONS.items():
                cam = make_camera(pattern, filters, method, space, seed)
                res = cam(scene, return_intermediates=True, generator=torch.Generator().manual_seed(seed))
                # Evaluate the linear sRGB output (before clipping and encoding): back to XYZ with the sRGB
                # matrix, white-patch scaled.
                rgb_to_xyz = torch.linalg.inv(cam.isp.xyz_to_display.matrix.to(res.image.dtype))
                xyz = torch.einsum("kc,bchw->bkhw", rgb_to_xyz, res.isp.display_linear)
                acc = macbeth_delta_e(patch_means(xyz), "D65")
                results.append({"illuminant": ill, "sensor": sname, "correction": cname,
                                "delta_e2000_mean": round(float(acc.mean[0]), 3),
                                "delta_e2000_max": round(float(acc.max[0]), 3),
                                "exposure_s": float(res.raw.exposure_s[0]),
                                "gains": [round(float(g), 4) for g in res.isp.gains[0]]})
                images[(ill, sname, cname)] = res.image[0]
                print(f"{ill:4s} {sname:11s} {cname:25s} mean dE2000 {acc.mean.item():6.2f}  max {acc.max.item():6.2f}")
    _figures(out, results, images)
    (out / "rgb_vs_cmy.json").write_text(json.dumps(results, indent=2))
    lines = ["# RGB vs CMY sensor, gray world in sensor space vs XYZ (Macbeth chart, sRGB output)", "",
             "Reference: the chart under D65 (white-patch scaled), measured on the linear sRGB output. Noise on, "
             "auto exposure, bilinear demosaic.", "",
             "| illuminant | sensor | illuminant correction | mean dE2000 | max dE2000 |", "|---|---|---|---|---|"]
    lines += [f"| {r['illuminant']} | {r['sensor']} | {r['correction']} | {r['delta_e2000_mean']:.2f} | "
              f"{r['delta_e2000_max']:.2f} |" for r in results]
    (out / "rgb_vs_cmy.md").write_text("\n".join(lines) + "\n")
    return {"results": results}


def _figures(out: Path, results: list, images: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [(ill, s) for ill in ILLUMINANTS for s in SENSORS]
    fig, axes = plt.subplots(len(rows), len(CORRECTIONS), figsize=(3.2 * len(CORRECTIONS), 2.3 * len(rows)))
    for i, (ill, s) in enumerate(rows):
        for j, c in enumerate(CORRECTIONS):
            r = next(r for r in results if (r["illuminant"], r["sensor"], r["correction"]) == (ill, s, c))
            ax = axes[i, j]
            ax.imshow(images[(ill, s, c)].permute(1, 2, 0).clamp(0, 1).numpy())
            ax.set_title(f"{ill}, {s}\n{c}: dE {r['delta_e2000_mean']:.2f}", fontsize=8)
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "rgb_vs_cmy.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 3.5))
    labels = [f"{r['illuminant']}\n{r['sensor'].split()[0]}\n{r['correction'].replace('gray world, ', 'GW ')}"
              for r in results]
    ax.bar(range(len(results)), [r["delta_e2000_mean"] for r in results],
           color=["C0" if "RGB" in r["sensor"] else "C1" for r in results])
    ax.set_xticks(range(len(results)), labels, fontsize=6)
    ax.set_ylabel("mean CIEDE2000")
    ax.set_title("Macbeth chart: RGB vs CMY sensor, gray world in sensor space vs XYZ")
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "rgb_vs_cmy_delta_e.png", dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/paper2004", help="output folder")
    p.add_argument("--patch-size", type=int, default=16, help="Macbeth patch size in scene pixels")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    run(Path(a.out), a.patch_size, a.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
