"""The joint denoise + demosaic model at every noise level (issue 35 item 4), against the better of two baselines.

For each noise condition on the [0, 1] mosaic (``var = a x + sigma^2``; white Gaussian at sigma 0, 0.005, 0.01,
0.02, 0.05 and Poisson-Gaussian shot noise at a = 0.001 and 0.01 with sigma 0; seed 0, the ``demosaic-eval``
noise), CPSNR (crop 10) on each image set of:

* ``nlmeans + menon2007``: scikit-image's non-local means on each CFA sub-plane (generalised Anscombe transform for
  shot noise), then Menon 2007 (at sigma 0: Menon alone);
* ``noise-free network``: the shipped noise-free network (``load_pretrained("noise_free")``, under its guard) on the
  noisy mosaic;
* ``joint (shipped)``: ``load_pretrained("joint_denoise")`` given the level (``isettorch/assets/
  demosaic_learned_denoise.pt`` under its guard and low-noise gate, ``learned.PRETRAINED_GATES``);
* ``joint (candidate)``: a checkpoint (``--candidate PATH``) given the level, under the shipped joint guard.

Reporting only: Kodak and McMaster are test sets (nothing here selects or tunes anything).

    OMP_NUM_THREADS=2 python benchmarks/demosaic_noise_levels.py --candidate out/.../best.pt \
        --out benchmarks/DEMOSAIC_NOISE_LEVELS.md
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch._machine import machine_info  # noqa: E402
from isettorch.isp import learned  # noqa: E402
from isettorch.isp.evaluation import evaluate_demosaic  # noqa: E402
from isettorch.paths import data_root  # noqa: E402

CONDITIONS = (("sigma 0", 0.0, 0.0), ("sigma 0.005", 0.005, 0.0), ("sigma 0.01", 0.01, 0.0),
              ("sigma 0.02", 0.02, 0.0), ("sigma 0.05", 0.05, 0.0), ("shot a 0.001", 0.0, 0.001),
              ("shot a 0.01", 0.0, 0.01))


def _models(candidate: str | None) -> dict:
    out = {"noise-free network": learned.load_pretrained("noise_free"),
           "joint (shipped)": learned.load_pretrained("joint_denoise")}
    if candidate:
        net = learned.load_checkpoint(candidate)[0]
        net.guard = dict(learned.PRETRAINED_GUARDS["joint_denoise"])
        out["joint (candidate)"] = net
    return out


def table(sets: dict, candidate: str | None, conditions=CONDITIONS, quiet: bool = True,
          reuse: dict | None = None) -> tuple[list[str], dict]:
    """The markdown table and its scores ``{(condition, set, row): dB}``; rows found in ``reuse`` (a previous run's
    scores, same keys) are taken from it instead of being scored again (the nlmeans rows take most of the time)."""
    models = _models(candidate)
    names = ["nlmeans + menon2007", *models]
    reuse = reuse or {}
    scores: dict = {}
    for label, sigma, shot in conditions:
        noisy = sigma > 0 or shot > 0
        for set_name, folder in sets.items():
            kw = {"noise_sigma": sigma, "noise_shot": shot, "seed": 0, "progress": not quiet}
            for name in names:
                if (label, set_name, name) in reuse:
                    scores[(label, set_name, name)] = reuse[(label, set_name, name)]
                elif name == names[0]:
                    scores[(label, set_name, name)] = evaluate_demosaic(
                        folder, "menon2007", "RGGB", 10, denoise="nlmeans" if noisy else None, **kw)["mean_cpsnr"]
                else:
                    scores[(label, set_name, name)] = evaluate_demosaic(folder, "learned", "RGGB", 10,
                                                                        model=models[name], **kw)["mean_cpsnr"]
            print(label, set_name, {n: round(scores[(label, set_name, n)], 2) for n in names}, flush=True)
    lines = []
    for set_name in sets:
        lines += [f"**{set_name}** (CPSNR dB, crop 10)", "",
                  "| method | " + " | ".join(c[0] for c in conditions) + " |",
                  "|---|" + "---|" * len(conditions)]
        for n in names:
            lines.append(f"| {n} | " + " | ".join(f"{scores[(c[0], set_name, n)]:.2f}" for c in conditions) + " |")
        for row in ("joint (shipped)", "joint (candidate)"):
            if row not in names:
                continue
            margin = []
            for c in conditions:
                best = max(scores[(c[0], set_name, names[0])], scores[(c[0], set_name, "noise-free network")])
                margin.append(f"{scores[(c[0], set_name, row)] - best:+.2f}")
            lines.append(f"| {row.split()[1][1:-1]} - best baseline | " + " | ".join(margin) + " |")
        lines.append("")
    return lines, scores


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--candidate", default=None, help="a joint DemosaicNet checkpoint to score beside the shipped one")
    p.add_argument("--kodak", default=str(data_root() / "kodak24"))
    p.add_argument("--mcmaster", default=str(data_root() / "mcmaster18"))
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", default=None, help="append the markdown table to this file")
    p.add_argument("--scores", default=None, help="write the scores as JSON here ([condition, set, row, dB] rows)")
    p.add_argument("--reuse", default=None, metavar="JSON",
                   help="take the rows this --scores file holds from it instead of scoring them again (name the "
                        "run that wrote it in the table's text)")
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    t0 = time.time()
    reuse = {tuple(r[:3]): r[3] for r in json.loads(Path(args.reuse).read_text())} if args.reuse else None
    lines, scores = table({"Kodak": Path(args.kodak), "McMaster": Path(args.mcmaster)}, args.candidate, reuse=reuse)
    if args.scores:
        Path(args.scores).write_text(json.dumps([[*k, v] for k, v in scores.items()], indent=0))
    env = machine_info()
    lines.append(f"Seed 0, RGGB, float32; wall {time.time() - t0:.0f} s; {json.dumps(env)}")
    text = "\n".join(lines)
    print(text)
    if args.out:
        with open(args.out, "a") as f:
            f.write("\n" + text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
