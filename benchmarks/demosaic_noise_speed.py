"""Two demosaic benchmark tables with ``isettorch.isp.evaluation.evaluate_demosaic`` (the ``demosaic-eval`` code):

* ``speed``: CPSNR (crop 10, noise-free) against milliseconds per megapixel (median over images, one call each after
  a warm-up; float32, CPU threads as given) for every classical and learned method, Kodak and McMaster.
* ``noise``: Kodak CPSNR (crop 10) at noise sigma 0.01 / 0.02 / 0.05 (seed 0) for menon2007 alone, each classical
  demosaic after ``--denoise nlmeans`` (and bm3d when installed), and the shipped joint learned model.

Reporting only: Kodak and McMaster are test sets (nothing here selects or tunes anything).

    OMP_NUM_THREADS=1 python benchmarks/demosaic_noise_speed.py speed --out benchmarks/DEMOSAIC_SPEED.md
    OMP_NUM_THREADS=1 python benchmarks/demosaic_noise_speed.py noise --out benchmarks/DEMOSAIC_NOISE.md
    python benchmarks/demosaic_noise_speed.py speed --device cuda --out benchmarks/DEMOSAIC_SPEED_CUDA.md

On CUDA the timings include ``torch.cuda.synchronize`` (``evaluate_demosaic``); the denoisers (scikit-image) run on
the CPU, with the mosaic copied there and back.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch._progress import add_quiet_argument  # noqa: E402
from isettorch.isp.evaluation import evaluate_demosaic  # noqa: E402
from isettorch.paths import data_root  # noqa: E402

DATA = data_root()  # $ISETTORCH_DATA (isettorch.paths)
SPEED_METHODS = ("nearest", "bilinear", "malvar2004", "menon2007", "learned")


def _median_ms_per_mp(res: dict, sizes: dict) -> float:
    return statistics.median(r["ms"] / (sizes[r["name"]] / 1e6) for r in res["images"])


def _sizes(folder: Path) -> dict:
    from isettorch.isp.evaluation import load_images

    return {n: a.shape[0] * a.shape[1] for n, a in load_images(folder)}


def _label(method: str, denoiser: str | None) -> str:
    """A noisy-table row's name: the denoiser before the demosaic, or the joint network."""
    if denoiser:
        return f"{denoiser} + {method}"
    return method + (" (joint denoise model)" if method == "learned" else "")


def speed(args) -> list[str]:
    sets = {"Kodak": Path(args.kodak), "McMaster": Path(args.mcmaster)}
    sizes = {k: _sizes(v) for k, v in sets.items()}
    header = ["| method | Kodak CPSNR | Kodak ms/MP | McMaster CPSNR | McMaster ms/MP |", "|---|---|---|---|---|"]

    def row(name: str, method: str, **kw) -> str:
        cells = []
        for k, folder in sets.items():
            res = evaluate_demosaic(folder, method, "RGGB", 10, device=args.device, progress=not args.quiet, **kw)
            cells += [f"{res['mean_cpsnr']:.2f}", f"{_median_ms_per_mp(res, sizes[k]):.1f}"]
        line = f"| {name} | " + " | ".join(cells) + " |"
        print(line, flush=True)
        return line

    rows = header + [row(m, m) for m in SPEED_METHODS]
    rows.append(row("learned + self-ensemble (2 passes)", "learned", self_ensemble=True))
    # the noisy case: the sequential baselines against the joint network, at one noise level
    s = args.speed_sigma
    rows += ["", f"With white Gaussian noise, sigma {s:g} (seed 0):", "", *header]
    rows += [row(_label(m, d), m, noise_sigma=s, seed=0, denoise=d)
             for m, d in (("menon2007", None), ("malvar2004", "nlmeans"), ("menon2007", "nlmeans"), ("learned", None))]
    return rows


def noise(args) -> list[str]:
    folder = Path(args.kodak)
    sigmas = [float(s) for s in args.sigmas.split(",")]
    denoisers = ["nlmeans"]
    try:
        import bm3d  # noqa: F401

        denoisers.append("bm3d")
    except ModuleNotFoundError:
        pass
    runs = [("menon2007", None)] + [(m, d) for d in denoisers for m in ("malvar2004", "menon2007")]
    runs.append(("learned", None))
    rows = ["| method | " + " | ".join(f"sigma {s:g}" for s in sigmas) + " |", "|---" * (len(sigmas) + 1) + "|"]
    for m, d in runs:
        cells = []
        for s in sigmas:
            res = evaluate_demosaic(folder, m, "RGGB", 10, noise_sigma=s, seed=0, denoise=d, device=args.device,
                                    progress=not args.quiet)
            cells.append(f"{res['mean_cpsnr']:.2f}")
        rows.append(f"| {_label(m, d)} | " + " | ".join(cells) + " |")
        print(rows[-1], flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("table", choices=("speed", "noise"))
    ap.add_argument("--kodak", default=str(DATA / "kodak24"))
    ap.add_argument("--mcmaster", default=str(DATA / "mcmaster18"))
    ap.add_argument("--sigmas", default="0.01,0.02,0.05")
    ap.add_argument("--speed-sigma", type=float, default=0.02, help="noise level of the speed table's noisy part")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu", help="where the demosaic runs (cpu, cuda); denoisers run on the CPU")
    ap.add_argument("--out", default=None, help="write the markdown table here")
    add_quiet_argument(ap)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    t0 = time.time()
    rows = (speed if args.table == "speed" else noise)(args)
    hw = {"platform": platform.platform(), "cpu_count": __import__("os").cpu_count(), "threads": args.threads,
          "torch": torch.__version__, "device": args.device}
    if torch.device(args.device).type == "cuda":
        hw["gpu"] = torch.cuda.get_device_name(torch.device(args.device))
    text = "\n".join(rows) + f"\n\nCrop 10, RGGB, float32, seed 0; wall {time.time() - t0:.0f} s; {json.dumps(hw)}\n"
    if args.out:
        Path(args.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
