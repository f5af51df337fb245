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

import torch  # noqa: E402

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model  # noqa: E402


def mhc_scores(sets: list[str]) -> dict:
    """Malvar-He-Cutler's per-image CPSNR on each set (the floor of the rule's condition c)."""
    return {s: [i["cpsnr"] for i in evaluate_demosaic(s, "malvar2004", "RGGB", 10)["images"]] for s in sets}


def score_network(net, sets: list[str], mhc: dict) -> dict:
    """One network's row: per set its mean, scenes below MHC, worst margin over MHC and per-image CPSNR; and the
    score (the mean of the set means); with a checkpoint path, ``path`` too. ``net``: a module or a checkpoint path
    (:func:`load_demosaic_model`)."""
    if not sets:
        raise ValueError("sets: expected at least one held-out folder")
    row = {}
    if not isinstance(net, torch.nn.Module):
        row["path"] = str(net)
        net = load_demosaic_model(net)
    for s in sets:
        r = evaluate_demosaic(s, "learned", "RGGB", 10, model=net)
        v = [i["cpsnr"] for i in r["images"]]
        row[s] = {"mean": r["mean_cpsnr"], "below_mhc": sum(a < b for a, b in zip(v, mhc[s])),
                  "worst_vs_mhc": min(a - b for a, b in zip(v, mhc[s])),
                  "per_image": {i["name"]: i["cpsnr"] for i in r["images"]}}
    row["score"] = sum(row[s]["mean"] for s in sets) / len(sets)
    return row


def passes(candidate: dict, incumbent: dict, sets: list[str], tolerance_db: float = 0.05) -> bool:
    """The rule on two rows of :func:`score_network`: a higher score, no set mean more than ``tolerance_db`` below
    the incumbent's, and no scene below MHC on any set."""
    return (candidate["score"] > incumbent["score"]
            and all(candidate[s]["mean"] >= incumbent[s]["mean"] - tolerance_db for s in sets)
            and all(candidate[s]["below_mhc"] == 0 for s in sets))


def interpolate_checkpoints(alpha: float, start: dict, finetuned: dict) -> dict:
    """The checkpoint of ``(1 - alpha) start + alpha finetuned`` (weight-space interpolation, "WiSE-FT": Wortsman et
    al., CVPR 2022): ``start``'s record with its weights replaced (float32) and its optimizer state dropped. The two
    must be the same architecture (same ``net_config`` and parameter names)."""
    if not 0 <= alpha <= 1:
        raise ValueError(f"alpha: expected a weight in [0, 1], got {alpha}")
    if set(start["model"]) != set(finetuned["model"]) or start["net_config"] != finetuned["net_config"]:
        raise ValueError("start, finetuned: expected checkpoints of the same architecture (net_config and parameter "
                         f"names), got {start['net_config']} and {finetuned['net_config']}")
    out = dict(start)
    out["model"] = {k: (1 - alpha) * start["model"][k].float() + alpha * finetuned["model"][k].float()
                    for k in start["model"]}
    out.pop("optimizer", None)
    return out


def screen(incumbent: str, candidate: str, sets: list[str], tolerance_db: float = 0.05) -> dict:
    """Score both checkpoints on every set; returns per-network rows (:func:`score_network`) and ``decision``:
    ``"candidate"`` or ``"incumbent"``."""
    if not sets:
        raise ValueError("sets: expected at least one held-out folder")
    mhc = mhc_scores(sets)
    res = {"incumbent": score_network(incumbent, sets, mhc), "candidate": score_network(candidate, sets, mhc)}
    res["decision"] = ("candidate" if passes(res["candidate"], res["incumbent"], sets, tolerance_db)
                       else "incumbent")
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
    ap = argparse.ArgumentParser(description="a run's pre-registered held-out screen")
    ap.add_argument("--candidate", default=None, metavar="PATH", help="score this checkpoint instead (a dry run)")
    dry = ap.parse_args(sys.argv[1:] if argv is None else argv).candidate
    if dry is not None:
        candidate, out = dry, dry_run_out
    torch.set_num_threads(2)
    return main(["--incumbent", incumbent, "--candidate", candidate, "--sets", *sets, "--out", out])


if __name__ == "__main__":
    raise SystemExit(main())
