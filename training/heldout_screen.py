"""The held-out shipping screen of the demosaic experiments: an incumbent network against a candidate on folders of
held-out synthetic scenes (``training/make_heldout.py``; never Kodak/McMaster), CPSNR with crop 10 on RGGB mosaics.

The rule (fixed in the stop-26/27 notes; each run's entry in :data:`RUNS` names its incumbent, candidate and sets
before the run): the score is the mean of the per-set means; the candidate ships if its score beats the incumbent's,
none of its set means is more than ``tolerance_db`` below the incumbent's, and no held-out scene is below
Malvar-He-Cutler on any set.

    python training/heldout_screen.py RUN [--candidate PATH] [--incumbent PATH] [--sets DIR ...] [--check]
    python training/heldout_screen.py --incumbent A.pt --candidate B.pt --sets out/heldout_v5 ... --out res.json

``RUN`` (a key of :data:`RUNS`, e.g. ``specular_2026-11-27``) runs that run's pre-registered screen: missing sets of
:data:`HELDOUT` are written first, and the result goes to the run's committed record (``result``). Any override
(``--candidate``, ``--incumbent``, ``--sets``) is a dry run and writes ``out/screen_dryrun/RUN.json`` instead;
``--check`` also prints how far each row's per-image CPSNR is from the committed record. The runs' records are in
``docs/training_log.md``.
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

#: ``training/make_heldout.py`` options of every screen's sets (24 x 256 px, linear sRGB, seeds never drawn in
#: training) and of each set (the commands in the specular and distill-4 pre-registrations, docs/training_log.md)
HELDOUT_BASE = ["--n", "24", "--size", "256", "--colour-space", "linear_srgb", "--quiet"]
_STRESS = ["--channel-gains", "1", "0.15", "0.15", "--grain-std", "0.005"]
HELDOUT = {
    "out/heldout_v5": [],
    "out/heldout_v5_stress": _STRESS,
    "out/heldout_stress": _STRESS + ["--natural", json.dumps({"components": {
        "colour_correlation": {"chromatic_radius_px": 16.0, "chromatic_detail_probability": 0.25},
        "grain": {"enabled": False}}})],
    "out/heldout_v5_relgrain": ["--natural", json.dumps({"components": {"grain": {"relative": {
        "probability": 0.5, "contrast": [0.01, 0.08]}}}})],
    "out/heldout_spec1": ["--natural", json.dumps({"components": {"specular": {"probability": 1.0}}})],
}
_SETS = list(HELDOUT)


def _best(name: str) -> str:
    return f"out/train_demosaic_noise_free_{name}/best.pt"


def _run(incumbent: str, candidate: str, n_sets: int, registered: str, **extra) -> dict:
    return {"incumbent": incumbent, "candidate": candidate, "sets": _SETS[:n_sets], "registered": registered, **extra}


#: each run's pre-registered screen, fixed before its checkpoints were scored (``registered``: when, and what the
#: candidate is): the incumbent and candidate checkpoints (paths from the repository root, as the runs wrote them),
#: the held-out sets, and the committed result (default ``training/runs/RUN/screen_heldout.json``). ``labels``:
#: the result's row names when they are not ``incumbent`` / ``candidate`` (the first screen's record). ``kind``:
#: ``best_of`` (``candidate`` a dict of named checkpoints, ``incumbent`` one of the names; :func:`best_of`),
#: ``interpolation``, ``validation`` (:func:`validation_screen`: the two on the held-out synthetic validation set of
#: the run's ``config``, a joint model's rule) or ``photos`` (:func:`photos_screen`); absent, the rule of
#: :func:`passes`. ``guard``: score both under that shipped variant's guard.
RUNS = {
    "dye_2026-11-26": _run(_best("stage3"), _best("dye"), 3, "2026-11-26 15:46 UTC, after the dyed-materials run "
                           "started, before any of its checkpoints was scored", labels=("stage3", "dye")),
    "relgrain_2026-11-26": _run(_best("stage3"), _best("relgrain"), 4, "2026-11-26 ~20:10 UTC, before the "
                                "multiplicative-grain run; the fourth set drawn with the candidate's grain option"),
    "distill_2026-11-27": _run(_best("stage3"), _best("distill"), 4, "2026-11-26 ~23:13 UTC, before the "
                               "self-ensemble distillation run"),
    "distill2_2026-11-27": _run(_best("distill"), _best("distill2"), 4, "2026-11-27 ~01:00 UTC, before the second "
                                "distillation round"),
    "distill3_2026-11-27": _run(_best("distill2"), _best("distill3"), 4, "2026-11-27 ~03:25 UTC, before the third "
                                "distillation round (dihedral teacher)"),
    "distill4_2026-11-27": _run(_best("distill3"), _best("distill4"), 4, "2026-11-27 ~05:15 UTC, before the fourth "
                                "distillation round (dihedral teacher, 4800 s, a fresh bank)"),
    "specular_2026-11-27": _run(_best("distill4"), _best("specular"), 5, "2026-11-27 ~07:23 UTC (0dac932), before "
                                "the specular run; the fifth set drawn with the candidate's specular option"),
    "specmix_2026-11-27": _run(_best("distill4"), _best("specmix"), 5, "2026-11-27 ~08:33 UTC (c631ce8), before "
                               "the specmix run (the specular run continued with the sheen in half the scenes)"),
    "distill5_2026-11-27": _run("out/wise_specular/best.pt", _best("distill5"), 5, "2026-11-27 ~10:10 UTC, before "
                                "the fifth distillation round (the shipped interpolation towards its own ensemble)"),
    # the guard in the loop (issue #35): both networks scored under the shipped noise-free guard, as they ship
    "guarded_2026-11-27": _run("isettorch/assets/demosaic_learned.pt", _best("guarded"), 5, "2026-11-27 ~20:30 UTC, "
                               "before the guard-in-the-loop fine-tune started", guard="noise_free"),
    # a joint model's rule (its noise is drawn in training): guarded CPSNR on the run's own held-out validation set
    "joint_guarded_2026-11-27": {"kind": "validation", "incumbent": "isettorch/assets/demosaic_learned_denoise.pt",
                                 "candidate": "out/train_demosaic_joint_guarded/best.pt",
                                 "config": "configs/train/demosaic_joint_guarded.yaml", "guard": "joint_denoise",
                                 "sets": [], "registered": "2026-11-27 ~20:20 UTC, before the joint guard-in-the-loop "
                                 "fine-tune started"},
    # the tiny network's second (distillation) step: the mean over the stress set's photographs decides
    "tiny_distill_2026-11-27": {"kind": "photos", "incumbent": "out/train_demosaic_tiny/best.pt",
                                "candidate": "out/train_demosaic_tiny_distill/best.pt", "guard": "tiny", "sets": [],
                                "result": "training/runs/family_2026-11-27/tiny_distill_screen.json",
                                "registered": "2026-11-27 ~21:15 UTC, before the distillation step started"},
    # the interpolation screen: W(alpha) = (1 - alpha) incumbent + alpha candidate for alpha = 0.1 ... 0.9, each
    # against the incumbent by the same rule; the passing alpha with the highest score ships (its network written to
    # out/wise_specular/best.pt: training.reproduce_demosaic.wise_select, which the reproduction runs too)
    # the stage-4/5 screen, before the shared rule: the candidate with the highest mean on the first set among those
    # that beat the incumbent there and have no scene below MHC on any set ships (best_of)
    "natural_v5_stage5_2026-11-26": _run(
        "stage3", {"stage3": _best("stage3"), "gpu_64x13": "out/gpu_stage4_64x13/best.pt", "stage4": _best("stage4"),
                   "stage5": _best("stage5")}, 3, "2026-11-26 13:30 UTC, before any of the candidates was scored on "
        "anything but its own run's validation set", kind="best_of"),
    "wise_specular_2026-11-27": _run(_best("distill4"), _best("specular"), 5, "2026-11-27 ~09:56 UTC, before any "
                                     "interpolated network was scored", kind="interpolation",
                                     result="training/runs/wise_specular_2026-11-27/wise_screen.json"),
}


def mhc_scores(sets: list[str]) -> dict:
    """Malvar-He-Cutler's per-image CPSNR on each set (the floor of the rule's condition c)."""
    return {s: [i["cpsnr"] for i in evaluate_demosaic(s, "malvar2004", "RGGB", 10)["images"]] for s in sets}


def _guarded(net, guard: str | None) -> torch.nn.Module:
    """``net`` (a module or a checkpoint path, :func:`load_demosaic_model`) as variant ``guard`` ships when given: its
    guard (``isettorch.isp.learned.PRETRAINED_GUARDS``), correction scale (``PRETRAINED_CORRECTION_SCALES``) and
    classical blend (``PRETRAINED_BLENDS``), whatever its checkpoint records. (Screens before 2026-11-29 ran with scale
    1 and no blend, all that was then shipped for the variants they name.)"""
    if not isinstance(net, torch.nn.Module):
        net = load_demosaic_model(net)
    if guard is not None:
        from isettorch.isp.learned import apply_shipped_settings

        apply_shipped_settings(net, guard)
    return net


def score_network(net, sets: list[str], mhc: dict, guard: str | None = None) -> dict:
    """One network's row: per set its mean, scenes below MHC, worst margin over MHC and per-image CPSNR; and the
    score (the mean of the set means); with a checkpoint path, ``path`` too. ``net``: a module or a checkpoint path
    (:func:`load_demosaic_model`). ``guard``: a shipped variant's name; the network is then scored under that
    variant's guard (``isettorch.isp.learned.PRETRAINED_GUARDS``), whatever guard its checkpoint records."""
    if not sets:
        raise ValueError("sets: expected at least one held-out folder")
    row = {}
    if not isinstance(net, torch.nn.Module):
        row["path"] = str(net)
    net = _guarded(net, guard)
    if guard is not None:
        row["guard"] = guard
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
    # the record (step, history, config, wall time) stays start's: said here, so that a card made of it does not
    # report start's step and validation as the interpolated network's
    out["interpolated"] = {"alpha": float(alpha), "start_step": start.get("step"),
                           "finetuned_step": finetuned.get("step")}
    return out


def screen(incumbent: str, candidate: str, sets: list[str], tolerance_db: float = 0.05,
           guard: str | None = None) -> dict:
    """Score both checkpoints on every set (both under the shipped ``guard`` of that variant when given); returns
    per-network rows (:func:`score_network`) and ``decision``: ``"candidate"`` or ``"incumbent"``."""
    if not sets:
        raise ValueError("sets: expected at least one held-out folder")
    mhc = mhc_scores(sets)
    res = {"incumbent": score_network(incumbent, sets, mhc, guard),
           "candidate": score_network(candidate, sets, mhc, guard)}
    res["decision"] = ("candidate" if passes(res["candidate"], res["incumbent"], sets, tolerance_db)
                       else "incumbent")
    return res


def _refuse_test_sets(sets) -> None:
    """A screen decides what ships: none of its sets may hold a test-set image (SystemExit naming ``--sets``)."""
    from training import common

    for s in sets:
        try:
            common.refuse_test_images(s, "--sets")
        except ValueError as err:
            raise SystemExit(str(err)) from err


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and not argv[0].startswith("-"):  # RUN [...]: a registered screen
        return screen_run(argv[0], argv[1:])
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog=f"or: heldout_screen.py RUN [--candidate PATH] [--incumbent PATH] [--sets DIR ...] [--check], a "
               f"pre-registered run's screen, RUN one of {', '.join(RUNS)}")
    ap.add_argument("--incumbent", required=True)
    ap.add_argument("--candidate", required=True)
    ap.add_argument("--sets", nargs="+", required=True)
    ap.add_argument("--tolerance-db", type=float, default=0.05)
    ap.add_argument("--out", default=None, help="write the JSON result here")
    args = ap.parse_args(argv)
    _refuse_test_sets(args.sets)
    res = screen(args.incumbent, args.candidate, args.sets, args.tolerance_db)
    for name in ("incumbent", "candidate"):
        row = res[name]
        print(name, " ".join(f"{row[s]['mean']:.3f}({row[s]['below_mhc']})" for s in args.sets),
              f"score {row['score']:.3f}", flush=True)
    print("ship:", res["decision"])
    if args.out:
        Path(args.out).write_text(json.dumps(res, indent=1))
    return 0


def best_of(incumbent: str, paths: dict, sets: list[str]) -> dict:
    """The stage-4/5 screen (``natural_v5_stage5_2026-11-26``; the rule before :func:`passes`): every network of
    ``paths`` (name -> checkpoint, the incumbent's name among them) and Malvar-He-Cutler (``malvar2004``) scored on
    every set, as ``{set: {name: row}}`` (rows of :func:`score_network`), and ``decision``: :func:`best_of_decision`."""
    mhc_rows = {s: evaluate_demosaic(s, "malvar2004", "RGGB", 10) for s in sets}
    mhc = {s: [i["cpsnr"] for i in r["images"]] for s, r in mhc_rows.items()}
    rows = {name: score_network(path, sets, mhc) for name, path in paths.items()}
    out = {s: {"malvar2004": {"mean": mhc_rows[s]["mean_cpsnr"], "below_mhc": 0, "worst_vs_mhc": 0.0,
                              "per_image": {i["name"]: i["cpsnr"] for i in mhc_rows[s]["images"]}},
               **{name: rows[name][s] for name in paths}} for s in sets}
    out["decision"] = best_of_decision(out, incumbent, sets)
    return out


def best_of_decision(res: dict, incumbent: str, sets: list[str]) -> str:
    """The candidate (a name of ``res[sets[0]]`` other than ``incumbent`` and ``malvar2004``) with the highest mean on
    ``sets[0]`` among those whose mean there beats the incumbent's and with no scene below MHC on any set; else the
    incumbent."""
    first = res[sets[0]]
    ok = {k: first[k]["mean"] for k in first if k not in (incumbent, "malvar2004")
          and first[k]["mean"] > first[incumbent]["mean"] and all(res[s][k]["below_mhc"] == 0 for s in sets)}
    return max(ok, key=ok.get) if ok else incumbent


def validation_screen(config: str, incumbent: str, candidate: str, guard: str | None = None) -> dict:
    """The two checkpoints on the held-out synthetic validation set of the training ``config``
    (``train_demosaic.make_validation``: scenes of their own seed, the run's domain and noise, never Kodak/McMaster),
    both under the shipped ``guard`` of that variant when given; ``decision``: ``"candidate"`` if its CPSNR is higher,
    else ``"incumbent"`` (a tie does not ship)."""
    from training import common, train_demosaic

    val = train_demosaic.make_validation(common.load_config(config))
    res = {name: {"path": str(path), "guard": guard, **train_demosaic.validate(_guarded(path, guard), val, "cpu")}
           for name, path in (("incumbent", incumbent), ("candidate", candidate))}
    res["decision"] = ("candidate" if res["candidate"]["val_cpsnr"] > res["incumbent"]["val_cpsnr"]
                       else "incumbent")
    return res


def photos_screen(incumbent: str, candidate: str, guard: str | None = None, size: int = 256) -> dict:
    """The two checkpoints on the stress set's scikit-image photographs (``training/stress_set.py`` PHOTOS, ``size``
    px centre crops, plain; never Kodak/McMaster), CPSNR crop 10, under the shipped ``guard`` of that variant when
    given; ``decision``: ``"candidate"`` if its mean is higher, else ``"incumbent"``. Menon's and MHC's rows are
    reported beside them."""
    from isettorch.isp.demosaicing import demosaic
    from isettorch.isp.learned import demosaic_learned
    from training import stress_set

    def classical(method):
        return lambda raw, pat: demosaic(raw, pat, method=method)

    def network(path):
        net = _guarded(path, guard)
        return lambda raw, pat: demosaic_learned(raw, pat, model=net)

    images = [(p, stress_set.photo(p, size)) for p in stress_set.PHOTOS]
    methods = {"menon2007": classical("menon2007"), "malvar2004": classical("malvar2004"),
               "incumbent": network(incumbent), "candidate": network(candidate)}
    scores = stress_set.score(images, methods)
    res = {name: {"mean": sum(v.values()) / len(v), "per_image": v} for name, v in scores.items()}
    for name, path in (("incumbent", incumbent), ("candidate", candidate)):
        res[name].update(path=str(path), guard=guard)
    res["decision"] = "candidate" if res["candidate"]["mean"] > res["incumbent"]["mean"] else "incumbent"
    return res


def result_path(run: str) -> Path:
    """The committed result of ``run``'s screen (relative to the repository root)."""
    return Path(RUNS[run].get("result", f"training/runs/{run}/screen_heldout.json"))


def make_sets(sets: list[str]) -> None:
    """Write the sets of :data:`HELDOUT` that are missing (``training/make_heldout.py``); other folders must exist."""
    from training import make_heldout

    for s in sets:
        if Path(s).is_dir():
            continue
        if s not in HELDOUT:
            raise ValueError(f"sets: {s} does not exist and is not one of the registered sets {list(HELDOUT)}")
        make_heldout.main(["--out", s, *HELDOUT_BASE, *HELDOUT[s]])


def compare_to_record(res: dict, record: dict, sets: list[str]) -> dict:
    """Per row (``incumbent``, ``candidate``), the largest |CPSNR difference| (dB) over the images of ``sets`` that
    ``res`` and the committed ``record`` (same row names) both score: how exactly a re-run reproduces the record."""
    out = {}
    for row in ("incumbent", "candidate"):
        diffs = [abs(v - record[row][s]["per_image"][k]) for s in sets if s in record.get(row, {})
                 for k, v in res[row][s]["per_image"].items() if k in record[row][s]["per_image"]]
        out[row] = max(diffs) if diffs else None
    return out


def screen_run(run: str, argv: list[str] | None = None) -> int:
    """``python training/heldout_screen.py RUN [...]``: ``run``'s pre-registered screen of :data:`RUNS` (see the
    module docstring; the registered paths are relative to the repository root, the working directory the runs used);
    prints both rows and the decision, and with ``--check`` the distance to the record."""
    if run not in RUNS:
        raise ValueError(f"run: expected one of {sorted(RUNS)}, got {run!r}")
    entry = RUNS[run]
    ap = argparse.ArgumentParser(prog=f"heldout_screen.py {run}", description=f"{run}: {entry['registered']}")
    ap.add_argument("--candidate", default=None, metavar="PATH", help="score this checkpoint instead (a dry run)")
    ap.add_argument("--incumbent", default=None, metavar="PATH", help="this incumbent instead (a dry run)")
    ap.add_argument("--sets", nargs="+", default=None, metavar="DIR", help="these sets instead (a dry run)")
    ap.add_argument("--check", action="store_true", help="print the per-image distance to the committed record")
    ap.add_argument("--out", default=None, help="write the result here (default: the record, or the dry-run file)")
    ap.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    args = ap.parse_args(argv)
    sets = args.sets or list(entry["sets"])
    dry = args.candidate is not None or args.incumbent is not None or args.sets is not None
    out = Path(args.out or (f"out/screen_dryrun/{run}.json" if dry else ROOT / result_path(run)))
    make_sets(sets)
    _refuse_test_sets(sets)
    torch.set_num_threads(args.threads)
    if entry.get("kind") == "best_of":  # --incumbent / --candidate replace those checkpoints
        paths = dict(entry["candidate"])
        if args.incumbent:
            paths[entry["incumbent"]] = args.incumbent
        if args.candidate:
            paths = {entry["incumbent"]: paths[entry["incumbent"]], "candidate": args.candidate}
        res = best_of(entry["incumbent"], paths, sets)
        for name in paths:
            print(name, " ".join(f"{res[s][name]['mean']:.3f}({res[s][name]['below_mhc']})" for s in sets), flush=True)
        print("ship:", res["decision"])
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(res, indent=1))
        return 0
    if entry.get("kind") in ("photos", "validation"):  # two checkpoints, one score each, the higher ships
        inc, cand = args.incumbent or entry["incumbent"], args.candidate or entry["candidate"]
        if entry["kind"] == "photos":
            res, rows, key = photos_screen(inc, cand, entry.get("guard")), ("menon2007", "malvar2004"), "mean"
        else:
            res, rows, key = validation_screen(entry["config"], inc, cand, entry.get("guard")), (), "val_cpsnr"
        for name in (*rows, "incumbent", "candidate"):
            print(name, f"{entry['kind']} {res[name][key]:.3f}", flush=True)
        print("ship:", res["decision"])
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(res, indent=1))
        return 0
    if entry.get("kind") == "interpolation":
        from training.reproduce_demosaic import WISE, wise_select

        _, res = wise_select(sets, args.incumbent or entry["incumbent"], args.candidate or entry["candidate"],
                             f"out/screen_dryrun/{run}" if dry else WISE["out"])
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(res, indent=1))
        return 0
    res = screen(args.incumbent or entry["incumbent"], args.candidate or entry["candidate"], sets,
                 guard=entry.get("guard"))
    for name in ("incumbent", "candidate"):
        row = res[name]
        print(name, " ".join(f"{row[s]['mean']:.3f}({row[s]['below_mhc']})" for s in sets),
              f"score {row['score']:.3f}", flush=True)
    print("ship:", res["decision"])
    if args.check:
        record = json.loads((ROOT / result_path(run)).read_text())
        inc, cand = entry.get("labels", ("incumbent", "candidate"))
        record = {"incumbent": record[inc], "candidate": record[cand]}
        for name, d in compare_to_record(res, record, sets).items():
            print(f"{name}: max |CPSNR - record| per image", "n/a" if d is None else f"{d:.2e} dB")
    labels = entry.get("labels")
    if labels:  # the record's own row names and decision
        res = {labels[0]: res["incumbent"], labels[1]: res["candidate"],
               "decision": labels[1] if res["decision"] == "candidate" else labels[0]}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    return 0


def run_rule(incumbent: str, candidate: str, sets: list[str], out: str, dry_run_out: str, argv=None) -> int:
    """A pre-registered screen given as arguments (checkpoints, sets, result file; :func:`screen_run` reads them
    from :data:`RUNS`): 2 torch threads, then :func:`main`. ``--candidate PATH`` in ``argv`` (default ``sys.argv``)
    scores that checkpoint instead, a dry run of the rule, and writes ``dry_run_out`` instead of ``out``."""
    ap = argparse.ArgumentParser(description="a run's pre-registered held-out screen")
    ap.add_argument("--candidate", default=None, metavar="PATH", help="score this checkpoint instead (a dry run)")
    dry = ap.parse_args(sys.argv[1:] if argv is None else argv).candidate
    if dry is not None:
        candidate, out = dry, dry_run_out
    torch.set_num_threads(2)
    return main(["--incumbent", incumbent, "--candidate", candidate, "--sets", *sets, "--out", out])


if __name__ == "__main__":
    raise SystemExit(main())
