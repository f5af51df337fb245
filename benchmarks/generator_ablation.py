"""Generator ablation: the same DemosaicNet trained for the same budget with each component of
:mod:`isettorch.data.natural` switched off, scored on Kodak and McMaster (CPSNR, crop 10). Reporting only: nothing is
selected on the test sets (each run keeps its best checkpoint by held-out *synthetic* validation).

    OMP_NUM_THREADS=1 python benchmarks/generator_ablation.py --steps 20000 --out out/ablation \\
        --table benchmarks/GENERATOR_ABLATION.md [--components palette fine_detail ...] [--set KEY=VALUE ...] \\
        [--seeds 0 1]

Runs are resumable (each is ``training/train_demosaic.py`` with ``--set data.disable=[name]`` in its own folder; a
finished run is not retrained). Every run trains on the current generator (``data.natural={}``:
``NATURAL_DEFAULTS``, whatever distribution the config pins, e.g. the version-4 one of
``demosaic_noise_free.yaml``). The table: one row per configuration ("all components" first), columns Kodak and
McMaster CPSNR and their difference from "all components", the run's steps, wall time and best validation CPSNR.
With ``--seeds``, every configuration is trained once per seed (in ``OUT/seed<S>``, with ``seed=S``: its own bank,
crops and validation scenes) and the table gives each seed's score, their mean and the mean's difference from "all
components", with the standard error of such a difference from the pooled between-seed variance of all rows.
A real run needs far more CPU than a test: ~9 configurations x the seeds x the budget.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch.data.natural import COMPONENTS, DEFAULT_COMPONENTS  # noqa: E402
from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model  # noqa: E402
from isettorch.paths import data_path  # noqa: E402
from training import train_demosaic  # noqa: E402

CONFIG = ROOT / "configs" / "train" / "demosaic_noise_free.yaml"


def run_one(name: str, disable: list[str], args, seed: int | None = None) -> dict:
    out = Path(args.out) / ("" if seed is None else f"seed{seed}") / name.replace(" ", "_")
    sets = [f"data.disable={json.dumps(disable)}", "data.natural={}", "eval.every=0", *args.set]
    if seed is not None:
        sets.append(f"seed={seed}")
    cmd = ["--config", str(args.config), "--out", str(out), "--steps", str(args.steps), "--quiet",
           "--threads", str(args.threads), "--set", *sets]
    rec_path = out / "record.json"
    if not (rec_path.is_file() and json.loads(rec_path.read_text())["steps"] >= args.steps):
        train_demosaic.main(cmd)
    rec = json.loads(rec_path.read_text())
    scores_path = out / "scores.json"  # the test-set scores of this run's best checkpoint (reporting only)
    if scores_path.is_file() and json.loads(scores_path.read_text()).get("steps") == rec["steps"]:
        return json.loads(scores_path.read_text())
    net = load_demosaic_model(out / "best.pt")
    row = {"name": name, "steps": rec["steps"], "wall_s": rec["wall_s"], "val": rec["best_val_cpsnr"]}
    for key, folder in (("kodak", args.kodak), ("mcmaster", args.mcmaster)):
        row[key] = evaluate_demosaic(folder, "learned", "RGGB", 10, model=net)["mean_cpsnr"]
    scores_path.write_text(json.dumps(row, indent=1))
    return row


def table(rows: list[dict]) -> str:
    ref = rows[0]
    lines = ["| generator | Kodak | d Kodak | McMaster | d McMaster | steps | wall s | val (own generator) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['name']} | {r['kodak']:.2f} | {r['kodak'] - ref['kodak']:+.2f} | {r['mcmaster']:.2f} | "
                     f"{r['mcmaster'] - ref['mcmaster']:+.2f} | {r['steps']} | {r['wall_s']:.0f} | {r['val']:.2f} |")
    return "\n".join(lines) + "\n"


def seed_table(rows: dict[str, list[dict]], seeds: list[int]) -> str:
    """``rows``: configuration name -> one score row per seed ("all components" first). Each configuration's mean over
    the seeds, its difference from the reference's, and the standard error of such a difference, ``s sqrt(2 / n)``
    with ``s^2`` the between-seed sample variance pooled over all rows (n seeds per row): the two-sample standard
    error of a difference of means with a pooled variance, as in Student's t test."""
    n = len(seeds)
    means = {name: {k: sum(r[k] for r in rs) / n for k in ("kodak", "mcmaster", "val")} for name, rs in rows.items()}
    ref = means[next(iter(rows))]
    se = {}
    for k in ("kodak", "mcmaster"):
        var = [sum((r[k] - means[name][k]) ** 2 for r in rs) / (n - 1) for name, rs in rows.items()]
        se[k] = (sum(var) / len(var) * 2 / n) ** 0.5
    per = " / ".join(f"seed {s}" for s in seeds)
    lines = [f"| generator | Kodak ({per}) | Kodak mean | d Kodak | McMaster ({per}) | McMaster mean | d McMaster "
             "| steps | wall s (sum) | val mean (own generator) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, rs in rows.items():
        m = means[name]
        kod, mcm = (" / ".join(f"{r[k]:.2f}" for r in rs) for k in ("kodak", "mcmaster"))
        lines.append(f"| {name} | {kod} | {m['kodak']:.2f} | "
                     f"{m['kodak'] - ref['kodak']:+.2f} | {mcm} | "
                     f"{m['mcmaster']:.2f} | {m['mcmaster'] - ref['mcmaster']:+.2f} | {rs[0]['steps']} | "
                     f"{sum(r['wall_s'] for r in rs):.0f} | {m['val']:.2f} |")
    return ("\n".join(lines) + f"\n\nStandard error of a 'd' (pooled between-seed variance of all rows, {n} seeds per "
            f"row): Kodak {se['kodak']:.2f} dB, McMaster {se['mcmaster']:.2f} dB.\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=str(CONFIG))
    ap.add_argument("--steps", type=int, default=20000, help="the fixed budget of every run")
    ap.add_argument("--out", default="out/ablation")
    ap.add_argument("--components", nargs="*", default=list(DEFAULT_COMPONENTS))
    ap.add_argument("--kodak", default=str(data_path("kodak24", must_exist=False)))
    ap.add_argument("--mcmaster", default=str(data_path("mcmaster18", must_exist=False)))
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--set", nargs="*", default=[], help="extra config overrides for every run (key.sub=value)")
    ap.add_argument("--table", default=None, help="write the markdown table here")
    ap.add_argument("--seeds", type=int, nargs="+", default=None,
                    help="train every configuration once per seed (OUT/seed<S>) and tabulate the means (>= 2 seeds)")
    ap.add_argument("--skip-reference", action="store_true",
                    help="do not run 'all components' (e.g. a second process sharing --out; the table needs it)")
    args = ap.parse_args(argv)
    bad = [c for c in args.components if c not in COMPONENTS]
    if bad:
        raise ValueError(f"--components: expected names from {COMPONENTS}, got {bad}")
    if args.seeds is not None:
        if len(args.seeds) < 2 or len(set(args.seeds)) != len(args.seeds) or args.skip_reference:
            raise ValueError(f"--seeds: expected two or more distinct seeds (and no --skip-reference), "
                             f"got {args.seeds}")
        names = {"all components": [], **{f"without {c}": [c] for c in args.components}}
        rows = {name: [run_one(name, dis, args, s) for s in args.seeds] for name, dis in names.items()}
        return _write(args, seed_table(rows, args.seeds), f", seeds {args.seeds}")
    rows = [] if args.skip_reference else [run_one("all components", [], args)]
    rows += [run_one(f"without {c}", [c], args) for c in args.components]
    if args.skip_reference:  # the table's first row must be "all components": run again without the flag
        return 0
    return _write(args, table(rows), "")


def _write(args, body: str, seeds: str) -> int:
    text = (f"# Generator ablation (DemosaicNet, {args.steps} steps each{seeds}, config {Path(args.config).name}, "
            f"overrides {args.set or 'none'})\n\nReporting only (Kodak/McMaster CPSNR, crop 10, of each run's best "
            "checkpoint by its own held-out synthetic validation; 'val' is scored on scenes of that run's generator, "
            "so it is not comparable between rows).\n\n" + body)
    if args.table:
        Path(args.table).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
