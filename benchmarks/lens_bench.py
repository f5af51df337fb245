"""Speed and error of LensOptics (eigen-PSF shift-variant blur) against the brute-force per-source PSF render.

Usage: OMP_NUM_THREADS=2 python benchmarks/lens_bench.py [--size 1024] [--repeats 5] [--out out/lens.md]

``--out`` replaces its file: benchmarks/LENS.md (the table and its hand-written notes) is curated by hand from it.

Scene: a seeded random texture (band-limited noise + edges) covering 98 % of the Cooke triplet's 40 deg field,
3 bands (486.1, 587.6, 656.3 nm), float32. Timings are medians of repeated renders with the PSF bank cached
(it depends only on the lens, wavelengths and grid; its one-off cost is reported separately). The reference is
`render_brute_force` (33 field heights x 64 azimuths, every source sample spread by its own PSF).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
import warnings

import torch

from isettorch.optics.lens.optics import LensOptics, render_brute_force
from isettorch.scene.scene import Scene


def scene(size: int, lens: LensOptics, dtype=torch.float32) -> Scene:
    g = torch.Generator().manual_seed(0)
    noise = torch.rand(1, 3, size // 8, size // 8, generator=g)
    x = torch.nn.functional.interpolate(noise, size=(size, size), mode="bicubic", align_corners=False)
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    x = x.clamp_min(0) + 0.5 * (((yy // 32) + (xx // 32)) % 2)  # sharp edges everywhere in the field
    t = math.tan(math.radians(lens.analysis.max_field_deg)) * 0.98
    hfov = 2 * math.degrees(math.atan(t / math.sqrt(2)))
    return Scene(x.to(dtype), torch.tensor([486.1, 587.6, 656.3], dtype=dtype), hfov_deg=hfov)


def main() -> None:
    warnings.filterwarnings("ignore")
    torch.set_num_threads(2)
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--lens", default="cooke_triplet")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    base = LensOptics(args.lens)
    s = scene(args.size, base)
    t0 = time.perf_counter()
    ref = render_brute_force(base, s).photons.double()
    t_ref = time.perf_counter() - t0
    rows = []
    for fs, az, k in ((5, 8, 4), (9, 16, 12), (13, 24, 8), (13, 24, 16), (17, 32, 16), (17, 32, 24)):
        o = LensOptics(base.analysis, field_samples=fs, azimuth_samples=az, components=k)
        o._cache.update({kk: v for kk, v in base._cache.items() if kk[0] == "radial"})  # shared distortion/RI
        t0 = time.perf_counter()
        with torch.no_grad():
            out = o(s)
        t_bank = time.perf_counter() - t0
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            with torch.no_grad():
                out = o(s)
            times.append(time.perf_counter() - t0)
        p = out.photons.double()
        err = float((p - ref).pow(2).mean().sqrt() / ref.pow(2).mean().sqrt())
        rows.append((fs, az, k, statistics.median(times), t_bank, err, out.metadata["psf_size"]))
        print(rows[-1], flush=True)
    lines = [f"# LensOptics speed vs error ({args.lens}, {args.size}x{args.size}, 3 bands, float32, "
             f"torch threads {torch.get_num_threads()})", "",
             f"Reference: `render_brute_force` (33 field heights x 64 azimuths, per-source PSFs), {t_ref:.1f} s. "
             "Error = relative RMS over the whole optical image. Render time = median of "
             f"{args.repeats} renders with the PSF bank cached; bank = first call (PSFs + SVD).", "",
             "| field_samples | azimuth_samples | components K | PSF size | render s | bank s | rel. RMS error |",
             "|---|---|---|---|---|---|---|"]
    for fs, az, k, t, tb, e, ps in rows:
        lines.append(f"| {fs} | {az} | {k} | {ps} | {t:.2f} | {tb:.1f} | {100 * e:.3f} % |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text)


if __name__ == "__main__":
    main()
