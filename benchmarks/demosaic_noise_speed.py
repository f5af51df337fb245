"""Two demosaic benchmark tables with ``isettorch.isp.evaluation.evaluate_demosaic`` (the ``demosaic-eval`` code):

* ``speed``: CPSNR (crop 10, noise-free) against milliseconds per megapixel (median over images, one call each after
  a warm-up, in ``--rounds`` interleaved passes over the methods, each image's median over them; float32, CPU threads
  as given) and its ratio to menon2007's in the same run, for every classical and learned method, Kodak and
  McMaster, then a few at ``--speed-sigma`` noise (in the same passes); with
  ``--plot PNG`` the Pareto chart of the noise-free rows (the speed-error family ``learned_tiny``,
  ``learned_small``, ``learned`` beside the classical methods; issue #35 item 3); with ``--bf16`` the learned
  members again with their convolutions in bfloat16 (``torch.autocast``: the base, blend and guard stay float32).
* ``noise``: Kodak CPSNR (crop 10) at noise sigma 0.01 / 0.02 / 0.05 (seed 0) for menon2007 alone, each classical
  demosaic after ``--denoise nlmeans`` (and bm3d when installed), and the shipped joint learned model.
* ``tight``: the time of one method against another (``--pair``, default ``learned_tiny,menon2007``) in a tight
  loop on each image: the two called alternately ``--repeats`` times (warm caches, the same sizes allocated again
  at once), each image's ratio of the fastest calls and of the median calls, the median over images. The ``speed``
  table's protocol (each method once per image and pass, the other methods' passes in between) is closer to
  demosaicing a photograph once; the two can differ by 10-15 % for methods with many full-resolution temporaries.

Reporting only: Kodak and McMaster are test sets (nothing here selects or tunes anything).

    OMP_NUM_THREADS=2 python benchmarks/demosaic_noise_speed.py speed --threads 2 --out out/demosaic_speed.md \
        --plot docs/_static/demosaic_pareto.png
    OMP_NUM_THREADS=1 python benchmarks/demosaic_noise_speed.py noise --out out/demosaic_noise.md
    OMP_NUM_THREADS=2 python benchmarks/demosaic_noise_speed.py tight --threads 2
    python benchmarks/demosaic_noise_speed.py speed --device cuda --out out/demosaic_speed_cuda.md

``--out`` replaces its file: benchmarks/DEMOSAIC_SPEED.md, DEMOSAIC_NOISE.md and DEMOSAIC_SPEED_CUDA.md keep each
run's history and notes, and are curated by hand from these outputs.

On CUDA the timings include ``torch.cuda.synchronize`` (``evaluate_demosaic``); the denoisers (scikit-image) run on
the CPU, with the mosaic copied there and back.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch._machine import machine_info  # noqa: E402
from isettorch._progress import add_quiet_argument  # noqa: E402
from isettorch.isp.evaluation import evaluate_demosaic  # noqa: E402
from isettorch.paths import data_root  # noqa: E402

DATA = data_root()  # $ISETTORCH_DATA (isettorch.paths)
SPEED_METHODS = ("nearest", "bilinear", "malvar2004", "menon2007", "learned_tiny", "learned_small", "learned")
LEARNED_ROWS = ("learned_tiny", "learned_small", "learned")


def _median_ms_per_mp(passes: list[dict], sizes: dict) -> float:
    """The median over images of each image's median time over ``passes`` (evaluate_demosaic's results for one set,
    the images in the same order), in ms per megapixel."""
    return statistics.median(statistics.median(im["ms"] for im in ims) / (sizes[ims[0]["name"]] / 1e6)
                             for ims in zip(*(res["images"] for res in passes)))


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
    header = ["| method | Kodak CPSNR | Kodak ms/MP | Kodak x menon2007 (same run) | McMaster CPSNR | McMaster ms/MP | "
              "McMaster x menon2007 (same run) |", "|---|---|---|---|---|---|---|"]

    points = {}  # noise-free rows: name -> {set: (cpsnr, ms/MP)}

    def measure(method: str, bf16: bool = False, **kw) -> dict:
        """{set: evaluate_demosaic's result} for one pass over both sets."""
        out = {}
        for k, folder in sets.items():
            # bf16: the networks' convolutions under autocast (DemosaicNet keeps its base, blend and guard in float32)
            with torch.autocast(torch.device(args.device).type, dtype=torch.bfloat16, enabled=bf16):
                out[k] = evaluate_demosaic(folder, method, "RGGB", 10, device=args.device, progress=not args.quiet,
                                           **kw)
        return out

    def table(group: list[tuple], passes: dict) -> list[str]:
        """The rows of ``group`` from their passes: the CPSNR (the same in every pass: the methods are deterministic),
        the median over images of each image's median time over the passes, and that time over the group's
        menon2007 row's (measured in the same passes)."""
        pts = {name: {k: (passes[name][0][k]["mean_cpsnr"],
                          _median_ms_per_mp([p[k] for p in passes[name]], sizes[k])) for k in sets}
               for name, *_ in group}
        out = []
        for name, _m, _kw, plot in group:
            if plot:
                points[name] = pts[name]
            cells = []
            for k in sets:
                cpsnr, ms = pts[name][k]
                cells += [f"{cpsnr:.2f}", f"{ms:.1f}", f"{ms / pts['menon2007'][k][1]:.2f}"]
            out.append(f"| {name} | " + " | ".join(cells) + " |")
            print(out[-1], flush=True)
        return out

    # every row in --rounds interleaved passes (every method once, then again), so that the machine's drift between
    # minutes falls on every method alike; each image's time is its median over the passes
    specs = [(m, m, {}, True) for m in SPEED_METHODS]
    specs.append(("learned + self-ensemble (2 passes)", "learned", {"self_ensemble": True}, True))
    if args.bf16:  # the chart gets the accurate member's point only (the fast ones' fall on their float32 points)
        specs += [(f"{m} (bf16 autocast)", m, {"bf16": True}, m == "learned") for m in LEARNED_ROWS]
    # the noisy case: the sequential baselines against the joint network, at one noise level
    s = args.speed_sigma
    noisy = [(_label(m, d), m, {"noise_sigma": s, "seed": 0, "denoise": d}, False)
             for m, d in (("menon2007", None), ("malvar2004", "nlmeans"), ("menon2007", "nlmeans"), ("learned", None))]
    clean_passes, noisy_passes = {name: [] for name, *_ in specs}, {name: [] for name, *_ in noisy}
    for _ in range(args.rounds):
        for group, passes in ((specs, clean_passes), (noisy, noisy_passes)):
            for name, method, kw, _plot in group:
                passes[name].append(measure(method, **kw))
    rows = header + table(specs, clean_passes)
    if args.plot:
        rows += ["", f"Pareto chart: `{args.plot}`"]
        _plot_pareto(points, args.plot, args.threads, args.device)
    rows += ["", f"With white Gaussian noise, sigma {s:g} (seed 0):", "", *header, *table(noisy, noisy_passes)]
    return rows


def _plot_pareto(points: dict, path: str, threads: int, device: str) -> None:
    """CPSNR against ms/MP (log), one panel per test set, the Pareto front (``bench.pareto_front``) dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from bench import pareto_front

    sets = list(next(iter(points.values())))
    fig, axes = plt.subplots(1, len(sets), figsize=(5.2 * len(sets), 4.2))
    for ax, k in zip(axes, sets):
        names = list(points)
        pts = [(points[n][k][1], -points[n][k][0]) for n in names]  # (time, error) both minimised
        front = pareto_front(pts)
        ax.plot([pts[i][0] for i in front], [-pts[i][1] for i in front], "--", color="0.6", lw=1, zorder=1)
        by_time = sorted(range(len(pts)), key=lambda i: pts[i][0])
        below = False
        for rank, i in enumerate(by_time):
            n, (t, e) = names[i], pts[i]
            learned = n.startswith("learned")
            ax.scatter([t], [-e], color="C3" if learned else "C0", marker="o" if learned else "s", zorder=2)
            # a label goes below its point when the next slower method scores higher (the line to it leaves
            # upwards), unless the previous label went below (two close labels would overlap), else above; the
            # fastest method's label above (below it would leave the axes)
            below = (0 < rank < len(by_time) - 1 and -pts[by_time[rank + 1]][1] > -e and not below)
            label = n.replace(" + self-ensemble (2 passes)", " x2").replace(" (bf16 autocast)", " bf16")
            ax.annotate(label, (t, -e), fontsize=7, xytext=(4, -10 if below else 5), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_xlabel(f"ms per megapixel ({device}, {threads} threads)")
        ax.set_ylabel("CPSNR, crop 10 (dB)")
        ax.set_title(k)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("Demosaic speed against error (dashed: Pareto front)", fontsize=10)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


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


def tight(args) -> list[str]:
    """Per set: the two methods' fastest-call ms/MP (median over images) and their ratio, per image then the median."""
    from isettorch.io.images import rgb8_to_tensor
    from isettorch.isp.demosaicing import demosaic, mosaic
    from isettorch.isp.evaluation import load_images

    pair = [m.strip() for m in args.pair.split(",")]
    if len(pair) != 2:
        raise ValueError(f"--pair: expected two methods 'A,B', got {args.pair!r}")
    a, b = pair
    rows = [f"| set | {a} ms/MP | {b} ms/MP | {a} / {b}, fastest calls | {a} / {b}, median calls |",
            "|---|---|---|---|---|"]
    for set_name, folder in (("Kodak", Path(args.kodak)), ("McMaster", Path(args.mcmaster))):
        ms = {a: [], b: []}
        r_fast, r_med = [], []
        for _name, array in load_images(folder):
            truth = rgb8_to_tensor(array)  # (as evaluate_demosaic)
            raw = mosaic(truth, "RGGB").to(device=args.device, dtype=torch.float32)
            mp = raw.numel() / 1e6
            times = {a: [], b: []}
            with torch.no_grad():
                for _ in range(3):  # warm-up (at a process's start this VM runs the first calls slowly for seconds)
                    for m in (a, b):
                        demosaic(raw, "RGGB", m)
                for _ in range(args.repeats):
                    for m in (a, b):
                        t0 = time.perf_counter()
                        demosaic(raw, "RGGB", m)
                        if raw.device.type == "cuda":
                            torch.cuda.synchronize(raw.device)
                        times[m].append(1e3 * (time.perf_counter() - t0) / mp)
            for m in (a, b):
                ms[m].append(min(times[m]))
            r_fast.append(min(times[a]) / min(times[b]))
            r_med.append(statistics.median(times[a]) / statistics.median(times[b]))
        text = (f"| {set_name} | {statistics.median(ms[a]):.1f} | {statistics.median(ms[b]):.1f} | "
                f"{statistics.median(r_fast):.2f} ({min(r_fast):.2f}-{max(r_fast):.2f}) | "
                f"{statistics.median(r_med):.2f} ({min(r_med):.2f}-{max(r_med):.2f}) |")
        print(text, flush=True)
        rows.append(text)
    rows += ["", f"Each image: the two methods alternated {args.repeats} times after a warm-up (float32, RGGB); "
             "ms/MP the median over images of each image's fastest call; ratios the median over images (their "
             "range in brackets)."]
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("table", choices=("speed", "noise", "tight"))
    ap.add_argument("--kodak", default=str(DATA / "kodak24"))
    ap.add_argument("--mcmaster", default=str(DATA / "mcmaster18"))
    ap.add_argument("--sigmas", default="0.01,0.02,0.05")
    ap.add_argument("--speed-sigma", type=float, default=0.02, help="noise level of the speed table's noisy part")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu", help="where the demosaic runs (cpu, cuda); denoisers run on the CPU")
    ap.add_argument("--out", default=None, help="write the markdown table here")
    ap.add_argument("--plot", default=None, metavar="PNG", help="speed: write the Pareto chart here")
    ap.add_argument("--rounds", type=int, default=3,
                    help="speed: interleaved passes over every method, noise-free and noisy (each image's time is "
                         "its median over them; default 3)")
    ap.add_argument("--bf16", action="store_true",
                    help="speed: also the learned members with their convolutions in bfloat16 (torch.autocast; fast on "
                         "CPUs with AVX512-BF16 or AMX, and on GPUs)")
    ap.add_argument("--pair", default="learned_tiny,menon2007", help="tight: the two methods 'A,B' (A's time over B's)")
    ap.add_argument("--repeats", type=int, default=15, help="tight: alternated calls per image (default 15)")
    add_quiet_argument(ap)
    args = ap.parse_args(argv)
    if args.rounds < 1:
        ap.error(f"--rounds: expected a positive number of passes, got {args.rounds}")
    if args.repeats < 1:
        ap.error(f"--repeats: expected a positive number of calls, got {args.repeats}")
    if args.table == "tight" and len(args.pair.split(",")) != 2:
        ap.error(f"--pair: expected two methods 'A,B', got {args.pair!r}")
    torch.set_num_threads(args.threads)
    t0 = time.time()
    rows = {"speed": speed, "noise": noise, "tight": tight}[args.table](args)
    hw = machine_info(args.device)
    rounds = f"{args.rounds} interleaved passes (every row), " if args.table == "speed" else ""
    text = "\n".join(rows) + (f"\n\nCrop 10, RGGB, float32, seed 0; {rounds}wall {time.time() - t0:.0f} s; "
                              f"{json.dumps(hw)}\n")
    if args.out:
        Path(args.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
