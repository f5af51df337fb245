"""How much the detached exposure rule changes a design's training gradient (reporting; issue #36).

``DesignCamera`` takes its exposure and analog gain from a white card (``docs/camera_design.md``). By default that
decision is detached from the graph; ``config.exposure.differentiable: true`` keeps it in. Where the exposure and the
gain are both at their limits the two gradients are the same; elsewhere the detached one leaves out "a slower lens
gets a longer exposure or more gain". This script measures how far apart they are for the f-number, on the
training loss of ``training/codesign.py`` (L1 in linear sRGB plus L1 in encoded sRGB, crop 4), for every shipped
design at each of its light levels.

Each of ``--batches`` batches (8 PairStream layout scenes of 64 x 64 pixels, ``measure``'s defaults; the codesign
trainer's default source, :func:`training.codesign_sources.source_layouts`) is rendered with the same noise for both
settings (common random numbers: one generator seed per batch). The table gives the f-number gradient summed over
the batches with the rule detached and kept in the graph, their relative difference, and the exposure and gain the
rule chose.

    python benchmarks/design_exposure_gradient.py [--designs bayer_rgb ...] [--batches 4] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch.data.config import seed_for  # noqa: E402
from isettorch.design import SHIPPED_DESIGNS, load_design  # noqa: E402
from isettorch.optics import DiffractionLimitedOptics  # noqa: E402
from training.codesign import _loss, merged_config  # noqa: E402
from training.codesign_sources import source_layouts, targets  # noqa: E402


def measure(design: str, *, batches: int = 4, batch: int = 8, size: int = 64, seed: int = 123) -> list[dict]:
    """One row per light level of ``design``: ``{"design", "lux", "detached", "in_graph", "relative",
    "exposure_s", "analog_gain"}`` (gradients of the summed batch losses in the f-number)."""
    cfg = merged_config({})
    cam = load_design(design)
    o = cam.config["optics"]
    cam.optics = DiffractionLimitedOptics(f_number=float(o["f_number"]), focal_length_m=float(o["focal_length_m"]),
                                          learn_f_number=True)
    rows = []
    for lux in cam.lux_levels:
        grads, settings = {}, {}
        for differentiable in (False, True):
            cam.config["exposure"]["differentiable"] = differentiable
            total = 0.0
            for k in range(batches):
                maps, refl = source_layouts(k, batch, size, cam, cfg, seed)
                scene = cam.scene(maps, refl, lux)
                gen = torch.Generator().manual_seed(seed_for(seed, k, stream=1))
                cap = cam.capture(scene, generator=gen)
                loss = _loss(cam.reconstruct(cap, lux), targets(maps, refl, cam), int(cfg["loss_crop"]), 1.0)
                (g,) = torch.autograd.grad(loss, cam.optics.f_number)
                total += float(g)
                settings = {k: float(cap[k][0].detach()) for k in ("exposure_s", "analog_gain")}
            grads[differentiable] = total
        rows.append({"design": design, "lux": lux, "detached": grads[False], "in_graph": grads[True],
                     "relative": (grads[False] - grads[True]) / abs(grads[True]), **settings})
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| design | lux | exposure (s) | gain | d loss / d N, detached | in the graph | detached - in graph, "
             "relative |", "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['design']} | {r['lux']:g} | {r['exposure_s']:.4f} | {r['analog_gain']:.2f} | "
                     f"{r['detached']:.4e} | {r['in_graph']:.4e} | {100 * r['relative']:+.2f} % |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--designs", nargs="+", default=list(SHIPPED_DESIGNS))
    p.add_argument("--batches", type=int, default=4)
    p.add_argument("--markdown", type=Path)
    a = p.parse_args(argv)
    if a.batches < 1:
        p.error(f"--batches: expected a positive count, got {a.batches}")
    torch.set_num_threads(2)
    rows = [r for d in a.designs for r in measure(d, batches=a.batches)]
    text = markdown(rows)
    print(text, end="")
    if a.markdown:
        a.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
