"""Issue 36 comparison: every camera design scored on the same photographs at each light level.

Usage::

    ISETTORCH_DATA=/path/to/data python benchmarks/design_comparison.py kodak24 \\
        [--designs bayer_rgb ycmy rgbw learned] [--lux L ...] [--noise-free] [--json OUT.json] [--markdown OUT.md]
        [--figure OUT.png]

Each design (a shipped name or a design file) goes through :func:`isettorch.design.evaluate_design`, the code
behind ``isettorch design-eval``: the photographs lifted to spectra under D65, rendered through the design's
camera at every light level it was trained for with the same noise seed for every design, reconstructed by its
network and scored against the photograph in sRGB (CPSNR, crop 10) and by the mean CIEDE2000. The table gives
each design's mean CPSNR and mean dE2000 per light level, and each design's CPSNR difference to Bayer RGB; the
figure plots both against light level, beside the learned design's filters and mosaic. ``--noise-free`` adds each
network's mean CPSNR on the noise-free capture and splits each design's mean squared error into that part and the
part its noise adds.

Photographs are test data only: nothing here trains, tunes or selects a design.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch.design import SHIPPED_DESIGNS, evaluate_design, load_design  # noqa: E402


def compare(designs: list[str], folder, *, lux=None, seed: int = 0, crop: int = 10, noise_free: bool = False,
            progress: bool = True) -> dict:
    """``{"folder", "seed", "crop", "designs": {design name: evaluate_design(...)}}`` for every design."""
    out = {}
    for d in designs:
        res = evaluate_design(d, folder, lux, seed=seed, crop=crop, noise_free=noise_free, progress=progress)
        if res["design"] in out:
            raise ValueError(f"designs: two designs are named {res['design']!r}")
        out[res["design"]] = res
    return {"folder": str(folder), "seed": seed, "crop": crop, "designs": out}


def markdown(result: dict, reference: str = "bayer_rgb") -> str:
    """A table: per design and light level, mean CPSNR (dB), its difference to ``reference`` and mean dE2000."""
    res = result["designs"]
    levels = sorted({k for r in res.values() for k in r["mean_cpsnr"]}, key=float)
    head = "| design | " + " | ".join(f"{k} lux: CPSNR (dB) / vs {reference} / dE2000" for k in levels) + " |"
    lines = [head, "|---|" + "---|" * len(levels)]
    ref = res.get(reference)
    for r in res.values():
        cells = []
        for k in levels:
            if k not in r["mean_cpsnr"]:
                cells.append("-")
                continue
            diff = (f"{r['mean_cpsnr'][k] - ref['mean_cpsnr'][k]:+.2f}" if ref is not None and k in ref["mean_cpsnr"]
                    else "-")
            cells.append(f"{r['mean_cpsnr'][k]:.2f} / {diff} / {r['mean_de2000'][k]:.2f}")
        lines.append(f"| {r['design']} | " + " | ".join(cells) + " |")
    n = len(next(iter(res.values()))["images"])
    lines += ["", f"{n} photographs of {result['folder']}, noise seed {result['seed']}, crop {result['crop']}."]
    if all("mean_cpsnr_noise_free" in r for r in res.values()):
        lines += ["", noise_split(result)]
    return "\n".join(lines) + "\n"


def noise_split(result: dict) -> str:
    """Per design and level: the mean CPSNR of the noise-free capture through the same network, and the mean squared
    error (sRGB, over the images' mean) split into the noise-free capture's and the part the noise adds."""
    res = result["designs"]
    levels = sorted({k for r in res.values() for k in r["mean_cpsnr_noise_free"]}, key=float)
    lines = ["| design | " + " | ".join(f"{k} lux: noise-free CPSNR (dB) / MSE = noise-free + noise (1e-3)"
                                       for k in levels) + " |", "|---|" + "---|" * len(levels)]
    for r in res.values():
        cells = []
        for k in levels:
            mse = sum(10 ** (-i["cpsnr"][k] / 10) for i in r["images"]) / len(r["images"])
            clean = sum(10 ** (-i["cpsnr_noise_free"][k] / 10) for i in r["images"]) / len(r["images"])
            cells.append(f"{r['mean_cpsnr_noise_free'][k]:.2f} / {1e3 * mse:.3f} = {1e3 * clean:.3f} + "
                         f"{1e3 * (mse - clean):.3f}")
        lines.append(f"| {r['design']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(result: dict, path: Path, learned: str | None = None) -> None:
    """CPSNR and dE2000 against light level for every design, and ``learned``'s filters and mosaic."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    res = result["designs"]
    panels = 4 if learned else 2
    fig, axes = plt.subplots(1, panels, figsize=(3.9 * panels, 3.6),
                             gridspec_kw={"width_ratios": [1.2, 1.2, 1.2, 0.7][:panels]})
    for r in res.values():
        lux = sorted(r["mean_cpsnr"], key=float)
        x = [float(v) for v in lux]
        axes[0].semilogx(x, [r["mean_cpsnr"][k] for k in lux], "o-", label=r["design"])
        axes[1].semilogx(x, [r["mean_de2000"][k] for k in lux], "o-", label=r["design"])
    axes[0].set_ylabel("mean CPSNR (dB, sRGB)")
    axes[1].set_ylabel("mean CIEDE2000")
    for a in axes[:2]:
        a.set_xlabel("scene illuminance (lux)")
        a.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    if learned:
        from training.codesign import draw_design

        cam = load_design(learned)
        draw_design(axes[2], axes[3], cam, f"design {cam.name}: filters")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", help="folder of 8-bit RGB photographs (a name under ISETTORCH_DATA, or a path)")
    p.add_argument("--designs", nargs="+", default=list(SHIPPED_DESIGNS), help="shipped names or design files")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--crop", type=int, default=10)
    p.add_argument("--lux", type=float, nargs="+", default=None, help="light levels (default: each design's own)")
    p.add_argument("--noise-free", action="store_true", help="also score the noise-free capture (the noise split)")
    p.add_argument("--json", type=Path, help="write the full result (per image) here")
    p.add_argument("--markdown", type=Path, help="write the table here")
    p.add_argument("--figure", type=Path, help="write the figure here")
    p.add_argument("--learned", default=None, help="the design whose filters and mosaic the figure shows")
    p.add_argument("--from-json", type=Path, help="redraw the table and figure from a saved --json result")
    args = p.parse_args(argv)
    from isettorch.paths import data_path

    if args.from_json:
        result = json.loads(args.from_json.read_text())
    else:
        result = compare(args.designs, data_path(args.folder), lux=args.lux, seed=args.seed, crop=args.crop,
                         noise_free=args.noise_free)
    table = markdown(result)
    print(table)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    if args.markdown:
        args.markdown.write_text(table)
    if args.figure:
        figure(result, args.figure, args.learned)
    return 0


if __name__ == "__main__":
    sys.exit(main())
