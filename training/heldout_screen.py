"""The held-out shipping screen of the demosaic experiments: an incumbent network against a candidate on folders of
held-out synthetic scenes (``training/make_heldout.py``; never Kodak/McMaster), CPSNR with crop 10 on RGGB mosaics.

The rule (fixed in the stop-26/27 notes; each run's ``screen_rule.py`` names its sets before the run): the score is
the mean of the per-set means; the candidate ships if its score beats the incumbent's, none of its set means is more
than ``tolerance_db`` below the incumbent's, and no held-out scene is below Malvar-He-Cutler on any set.

    python training/heldout_screen.py --incumbent A.pt --candidate B.pt --sets out/heldout_v5 ... --out res.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model  # noqa: E402


def screen(incumbent: str, candidate: str, sets: list[str], tolerance_db: float = 0.05) -> dict:
    """Score both checkpoints on every set; returns per-network rows (per-set mean, scenes below MHC, worst margin
    over MHC, per-image CPSNR, score) and ``decision``: ``"candidate"`` or ``"incumbent"``."""
    if not sets:
        raise ValueError("sets: expected at least one held-out folder")
    res = {}
    mhc = {s: [i["cpsnr"] for i in evaluate_demosaic(s, "malvar2004", "RGGB", 10)["images"]] for s in sets}
    for name, path in (("incumbent", incumbent), ("candidate", candidate)):
        net, row = load_demosaic_model(path), {"path": str(path)}
        for s in sets:
            r = evaluate_demosaic(s, "learned", "RGGB", 10, model=net)
            v = [i["cpsnr"] for i in r["images"]]
            row[s] = {"mean": r["mean_cpsnr"], "below_mhc": sum(a < b for a, b in zip(v, mhc[s])),
                      "worst_vs_mhc": min(a - b for a, b in zip(v, mhc[s])),
                      "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
        row["score"] = sum(row[s]["mean"] for s in sets) / len(sets)
        res[name] = row
    a, b = res["candidate"], res["incumbent"]
    ok = (a["score"] > b["score"] and all(a[s]["mean"] >= b[s]["mean"] - tolerance_db for s in sets)
          and all(a[s]["below_mhc"] == 0 for s in sets))
    res["decision"] = "candidate" if ok else "incumbent"
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--incumbent", required=True)
    ap.add_argument("--candidate", required=True)
    ap.add_argument("--sets", nargs="+", required=True)
    ap.add_argument("--tolerance-db", type=float, default=0.05)
    ap.add_argument("--out", default=None, help="write the JSON result here")
    args = ap.parse_args(argv)
    res = screen(args.incumbent, args.candidate, args.sets, args.tolerance_db)
    for name in ("incumbent", "candidate"):
        row = res[name]
        print(name, " ".join(f"{row[s]['mean']:.3f}({row[s]['below_mhc']})" for s in args.sets),
              f"score {row['score']:.3f}", flush=True)
    print("ship:", res["decision"])
    if args.out:
        Path(args.out).write_text(json.dumps(res, indent=1))
    return 0


def run_rule(incumbent: str, candidate: str, sets: list[str], out: str, dry_run_out: str, argv=None) -> int:
    """A run's pre-registered screen (its ``screen_rule.py`` names the checkpoints, sets and result file): 2 torch
    threads, then :func:`main`. ``--candidate PATH`` in ``argv`` (default ``sys.argv``) scores that checkpoint
    instead, a dry run of the rule, and writes ``dry_run_out`` instead of ``out``."""
    import torch

    ap = argparse.ArgumentParser(description="a run's pre-registered held-out screen")
    ap.add_argument("--candidate", default=None, metavar="PATH", help="score this checkpoint instead (a dry run)")
    dry = ap.parse_args(sys.argv[1:] if argv is None else argv).candidate
    if dry is not None:
        candidate, out = dry, dry_run_out
    torch.set_num_threads(2)
    return main(["--incumbent", incumbent, "--candidate", candidate, "--sets", *sets, "--out", out])


if __name__ == "__main__":
    raise SystemExit(main())
