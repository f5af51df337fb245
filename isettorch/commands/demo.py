"""``isettorch demo``: render the built-in scenes and write images and a short report to ``--out``."""

from __future__ import annotations

import json
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("demo", help="render built-in scenes and write images and a report to --out")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.set_defaults(func=run)


def run(args) -> int:
    import torch
    from PIL import Image

    from .. import spectral
    from ..scene import Scene

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    w = spectral.default_wavelengths()
    ill = spectral.energy_to_photons(spectral.illuminant("D65", w), w, dim=0)
    scene = Scene(ill[None, :, None, None].expand(1, -1, 64, 64).clone(), w, name="uniform D65",
                  illuminant_photons=ill).set_mean_luminance(100.0)
    rgb = (scene.srgb()[0].permute(1, 2, 0).clamp(0, 1) * 255).round().to(torch.uint8).numpy()
    Image.fromarray(rgb).save(out / "uniform_d65.png")
    report = {"scenes": [{"name": scene.name, "mean_luminance_cd_m2": float(scene.mean_luminance()[0])}]}
    (out / "report.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    return 0
