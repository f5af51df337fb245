"""Error of LensOptics' linear interpolation of PSFs between field heights, per interval, for a uniform grid of
field heights and for the shipped grid (:func:`isettorch.optics.lens.optics.field_radii_mm`, denser at the edge).

Usage: OMP_NUM_THREADS=1 python benchmarks/lens_field_grid.py [--lenses cooke_triplet double_gauss]
       [--pitch-um 4 2] [--samples 13] [--wavelength-nm 550]

For each interval of the grid (image radius 0 to the chief-ray height of the lens's largest field, at the primary
wavelength), the PSF computed at a quarter, half and three quarters of the interval (the same sampler LensOptics
uses: ``otf_sampler`` + ``psf_on_grid``, azimuths 0 and 45 deg) is compared with the linear interpolation of the
interval's end PSFs; the table gives the largest L1 difference per interval (PSFs sum to 1, so 200 % is disjoint).
"""

from __future__ import annotations

import argparse
import math

import torch

from isettorch.optics.lens.optics import LensOptics, _interp, field_radii_mm
from isettorch.optics.lens.psf import otf_sampler, psf_on_grid, spot_radius_mm


def interval_errors(lens: str, pitch_um: float, samples: int, wavelength_nm: float) -> dict:
    opt = LensOptics(lens)
    a = opt.analysis
    theta_ref, y_ref, _ = opt._radial_tables(a.reference_wavelength_nm)
    r_max = float(y_ref[-1]) * 0.999
    dx = pitch_um * 1e-3
    reach = max(spot_radius_mm(a, f, wavelength_nm) for f in (0.0, 0.5, 1.0))
    reach += 3 * wavelength_nm * 1e-6 * float(opt.f_number)
    size = min(max(2 * int(math.ceil(reach / dx)) + 1, 3), 129)
    az = torch.tensor([0.0, math.pi / 4], dtype=torch.float64)
    cache: dict = {}

    def psf(r: float) -> torch.Tensor:
        key = round(r, 12)
        if key not in cache:
            f = (_interp(torch.tensor([r], dtype=torch.float64), y_ref, theta_ref) / a.max_field_deg).clamp(0, 1)
            cache[key] = psf_on_grid(otf_sampler(a, float(f[0]), wavelength_nm), az, dx, size)
        return cache[key]

    grids = {"uniform": torch.linspace(0, r_max, samples, dtype=torch.float64).tolist(),
             "shipped": field_radii_mm(r_max, samples).tolist()}
    out = {}
    for name, r in grids.items():
        errs = []
        for i in range(samples - 1):
            e = 0.0
            for t in (0.25, 0.5, 0.75):
                mid = (1 - t) * psf(r[i]) + t * psf(r[i + 1])
                e = max(e, float((mid - psf(r[i] + t * (r[i + 1] - r[i]))).abs().sum((-1, -2)).max()))
            errs.append(e)
        out[name] = errs
    return {"size": size, "errors": out}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--lenses", nargs="+", default=["cooke_triplet", "double_gauss"])
    ap.add_argument("--pitch-um", nargs="+", type=float, default=[4.0, 2.0])
    ap.add_argument("--samples", type=int, default=13)
    ap.add_argument("--wavelength-nm", type=float, default=550.0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    print("| lens | pitch um | grid | largest % | mean % | per interval, axis to edge (%) |")
    print("|---|---|---|---|---|---|")
    for lens in args.lenses:
        for p in args.pitch_um:
            res = interval_errors(lens, p, args.samples, args.wavelength_nm)
            for name, errs in res["errors"].items():
                print(f"| {lens} | {p:g} | {name} | {100 * max(errs):.1f} | {100 * sum(errs) / len(errs):.1f} | "
                      + " ".join(f"{100 * e:.1f}" for e in errs) + " |", flush=True)


if __name__ == "__main__":
    main()
