"""How much a colour-filter design can gain from its photons alone: the noise-limited colour estimate of a flat
patch, per shipped camera design and light level (reporting; issue #36).

For each design (:data:`isettorch.design.SHIPPED_DESIGNS`) its own camera (optics, sensor, exposure rule) captures the
24 Macbeth patches (ISETCam's reflectances, :func:`isettorch.scene.macbeth.macbeth_reflectances`) under D65 at each
light level, noise-free; ``rho[r, c]`` is the mean photo-electron count of channel ``c``'s pixels on patch ``r``. A
window of ``N`` pixels holding a fraction ``f_c`` of channel ``c`` estimates each channel's mean with variance
``(rho + read^2 + dark + lsb^2 / 12) / (f_c N)`` (Poisson shot noise, the sensor's read noise, dark signal and ADC
step in electrons at the capture's gain). The best linear estimate of the patch's linear sRGB (white = 1,
:func:`isettorch.design.linear_srgb_of_reflectance`) from those means is the Wiener (linear MMSE) map over the 24
patches, ``M = T' P (P' P + R S)^-1`` (Kay, Fundamentals of Statistical Signal Processing I, 1993, 12.6); its mean
squared error is the colour bias of a linear correction plus the noise it passes, ``trace(M S M') / 3``. The table
gives each design's error against Bayer's in dB (positive: better) for windows of 4 to 256 pixels.

What it leaves out is the demosaic itself (spatial detail, aliasing, the chroma resolution lost to clear pixels): it
is the part of a design's advantage that photons and colour can give a reconstruction that averages N pixels.

    python benchmarks/design_noise_bound.py [--lux 1 10 100] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch.design import (  # noqa: E402
    SHIPPED_DESIGNS,
    bound_patches,
    colour_estimate_mse,
    load_design,
    patch_signals,
)
from isettorch.scene.macbeth import macbeth_reflectances  # noqa: E402

WINDOWS = (4, 16, 64, 256)
GREY = 21  # Macbeth "neutral 5 (.70 D)", reflectance about 0.19


def channel_electrons(camera, lux: float, size: int | None = None) -> dict:
    """Noise-free capture of the 24 patches (:func:`isettorch.design.patch_signals`): per-channel mean electrons
    ``[24, C]`` of the channels the mosaic uses, their pixel fractions, the per-pixel variance, exposure and gain."""
    refl = macbeth_reflectances(camera.wavelengths_nm, dtype=torch.float64)
    with torch.no_grad():
        return patch_signals(camera, refl, lux, size=size)


def wiener_mse(rho: torch.Tensor, var: torch.Tensor, frac: torch.Tensor, target: torch.Tensor, window: int) -> float:
    """Mean squared error (per sRGB channel, over the patches) of the Wiener map from channel means to ``target``
    (:func:`isettorch.design.colour_estimate_mse`)."""
    return float(colour_estimate_mse({"rho": rho, "var": var, "frac": frac, "target": target}, window))


def transfer_db(signals: dict, reference: dict) -> dict:
    """The error of a Wiener colour correction fitted on the generator's materials and applied to the ``photo`` and
    ``macbeth`` sets (``signals``: :func:`isettorch.design.patch_signals` of each set for one design), against
    ``reference``'s, in dB per window (positive: better)."""
    return {key: [10 * math.log10(float(colour_estimate_mse(reference["fit"], w, reference[key])
                                        / colour_estimate_mse(signals["fit"], w, signals[key]))) for w in WINDOWS]
            for key in ("photo", "macbeth")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lux", type=float, nargs="+", default=[1.0, 10.0, 100.0])
    ap.add_argument("--designs", nargs="+", default=list(SHIPPED_DESIGNS),
                    help="shipped design names or design files (default: the shipped designs)")
    ap.add_argument("--markdown", default=None, help="append the tables here")
    args = ap.parse_args(argv)
    designs = {name: load_design(name).eval() for name in dict.fromkeys(["bayer_rgb", *args.designs])}
    lines = ["| lux | design | channels (electrons on neutral 5) | exposure (s), gain | "
             + " | ".join(f"N = {w}" for w in WINDOWS) + " |", "|---" * (4 + len(WINDOWS)) + "|"]
    for lux in args.lux:
        res = {name: channel_electrons(cam, lux) for name, cam in designs.items()}
        ref = {w: wiener_mse(**{k: res["bayer_rgb"][k] for k in ("rho", "var", "frac", "target")}, window=w)
               for w in WINDOWS}
        for name, r in res.items():
            db = [10 * math.log10(ref[w] / wiener_mse(r["rho"], r["var"], r["frac"], r["target"], w))
                  for w in WINDOWS]
            grey = ", ".join(f"{c} {float(v):.1f}" for c, v in zip(r["names"], r["rho"][GREY]))
            lines.append(f"| {lux:g} | {name} | {grey} | {r['exposure_s']:.4f}, {r['gain']:.2f} | "
                         + " | ".join(f"{d:+.2f}" for d in db) + " |")
    patches = bound_patches(designs["bayer_rgb"].wavelengths_nm)
    lines += ["", "Correction fitted on the generator's materials, applied to colours lifted as photographs are "
              "(photo) and to the Macbeth chart (dB against bayer_rgb):", "",
              "| lux | design | photo: " + " | ".join(f"N = {w}" for w in WINDOWS) + " | Macbeth: "
              + " | ".join(f"N = {w}" for w in WINDOWS) + " |", "|---" * (2 + 2 * len(WINDOWS)) + "|"]
    for lux in args.lux:
        with torch.no_grad():  # each design's capture of the three sets, once per level
            sig = {name: patch_signals(cam, {k: patches[k] for k in ("fit", "photo", "macbeth")}, lux)
                   for name, cam in designs.items()}
        for name in designs:
            t = transfer_db(sig[name], sig["bayer_rgb"])
            lines.append(f"| {lux:g} | {name} | " + " | ".join(f"{d:+.2f}" for d in t["photo"] + t["macbeth"]) + " |")
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        with open(args.markdown, "a") as f:
            f.write("\n" + text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
