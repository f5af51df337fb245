"""Statistics of the natural-scene generator (isettorch.data.natural) against published natural-image statistics.

For N scenes per configuration (white-balanced Nikon D5100 camera RGB, 128 px, linear), the table gives the mean
(and std over scenes) of: the power-spectrum slope of the channel mean (van der Schaaf & van Hateren, Vision Res.
36, 1996: 1/f^alpha with alpha = 1.88 +- 0.43 over 276 calibrated natural images, i.e. slope -1.88); the kurtosis of
its first differences (heavy-tailed in natural images, far above a Gaussian's 3: Huang & Mumford, CVPR 1999;
Simoncelli & Olshausen, Annu. Rev. Neurosci. 2001); and the correlation of the R-G and R-B first differences
(high in natural images: Gunturk, Altunbasak & Mersereau, IEEE TIP 2002, the basis of demosaicing); and, pooled over
the scenes' 16 px windows, the detail-ratio exponent (isettorch.metrics.image_statistics.detail_ratio_exponent: 1 when
fine detail multiplies every channel alike, the colour-ratio prior; 0 when it adds alike, the colour-difference
prior). Rows: the full generator, each component switched off, the optional specular component on in every scene, and
the older isettorch.data.generate_scene layouts. Never Kodak/McMaster.

    OMP_NUM_THREADS=1 python benchmarks/scene_stats.py --n 24 --out benchmarks/SCENE_STATS.md
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch import spectral  # noqa: E402
from isettorch.data import generate_scene  # noqa: E402
from isettorch.data import natural as nat  # noqa: E402
from isettorch.data import spectra as sp  # noqa: E402
from isettorch.metrics import image_statistics as st  # noqa: E402

PUBLISHED = "| natural images (published) | -1.88 +- 0.43 (van der Schaaf & van Hateren 1996) | >> 3 (heavy-tailed) " \
            "| high (Gunturk et al. 2002) | high | no published value |"


def _stats(rgb: torch.Tensor) -> tuple[float, float, float, float]:
    lum = rgb.mean(0)
    return (st.power_spectrum_slope(lum), st.gradient_kurtosis(lum), st.cross_channel_gradient_correlation(rgb, 0, 1),
            st.cross_channel_gradient_correlation(rgb, 0, 2))


def _row(name: str, values: list, images: list) -> str:
    a = np.asarray(values)
    cells = [f"{m:.2f} +- {s:.2f}" for m, s in zip(a.mean(0), a.std(0))]
    beta, windows = st.detail_ratio_exponent(images)
    return f"| {name} | " + " | ".join(cells) + f" | {beta:.2f} ({windows} windows) |"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    ap.add_argument("--colour-space", default="d5100", choices=("d5100", "linear_srgb"),
                    help="d5100: the Nikon D5100's white-balanced camera RGB; linear_srgb: CIE 1931 XYZ through the "
                         "IEC 61966-2-1 matrix, von Kries-balanced to the scene's white (the training pool's space)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    t0 = time.time()
    wl = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    if args.colour_space == "d5100":
        sens = sp.camera_sensitivities("Nikon 5100 (NPL)", wl)
        space = "Nikon D5100 white-balanced linear RGB"
    else:
        from isettorch.isp.colour import XYZ_TO_LINEAR_SRGB

        sens = torch.tensor(XYZ_TO_LINEAR_SRGB, dtype=torch.float64) @ spectral.cmfs(wl, dtype=torch.float64)
        space = "linear sRGB (CIE 1931 XYZ, IEC 61966-2-1 matrix), white-balanced"
    rows = ["| scenes | spectrum slope | gradient kurtosis | corr. dR-dG | corr. dR-dB | detail-ratio exponent |",
            "|---|---|---|---|---|---|", PUBLISHED]
    m = (sens * spectral.wavelength_weights(wl)[None]).float()  # photon counting with the band widths
    configs = ([("natural (all components)", (), {})] + [(f"natural without {c}", (c,), {})
                                                        for c in nat.DEFAULT_COMPONENTS]
               + [("natural + specular in every scene", (), {"specular": {"probability": 1.0}})])
    for name, off, extra in configs:
        cfg = nat.natural_config({"size": args.size, "components": extra}, disable=off)
        vals, images = [], []
        for i in range(args.n):
            sc = nat.to_scene(nat.generate_natural(i, args.seed, cfg))
            images.append(sc.project(m.T)[0] / (sc.illuminant_photons[0] @ m.T)[:, None, None])
            vals.append(_stats(images[-1]))
        rows.append(_row(name, vals, images))
        print(rows[-1], flush=True)
    vals, images = [], []
    for i in range(args.n):
        s = generate_scene(i, seed=args.seed, config={"height": args.size, "width": args.size})
        images.append(s.project(m.T)[0] / (m @ s.illuminant_photons[0])[:, None, None])
        vals.append(_stats(images[-1]))
    rows.append(_row("isettorch.data.generate_scene (layouts)", vals, images))
    text = (f"# Scene statistics of the synthetic generators\n\n`python benchmarks/scene_stats.py --n {args.n} "
            f"--colour-space {args.colour_space}` "
            f"(seed {args.seed}, {args.size} px, {space}; mean +- std over scenes; "
            f"slope fitted from 4 cycles/image to 0.25 cycles/pixel, Hann window; {time.time() - t0:.0f} s)\n\n"
            + "\n".join(rows) + "\n")
    if args.out:
        Path(args.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
