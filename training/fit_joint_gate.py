"""Choose the joint demosaic network's noise gates (``isettorch.isp.learned.PRETRAINED_GATES``) on held-out synthetic
scenes (``training/make_heldout.py`` sets; never Kodak/McMaster).

For each set and noise level (``var = a x + sigma^2`` on the [0, 1] mosaic, the ``demosaic-eval`` noise, seed 0),
the parts of the shipped output run once; each candidate gate blends them and is scored (CPSNR, crop 10).

* ``--gate low`` (the low-noise gate, ``sigma_max``): the guarded noise-free and the guarded joint networks (the
  joint one without its gates), blended with :func:`isettorch.isp.learned.level_gate_weight`. Rule pre-registered
  in ``docs/training_log.md#joint_gate_2026-11-28``.
* ``--gate classical`` (the high-noise gate, ``sigma_start``, ``sigma_full``, ``weight_max``): the joint network
  under its guard and its shipped low-noise gate, and the classical expert
  (:func:`isettorch.isp.learned.classical_expert`: nlmeans on the CFA sub-planes, then Menon 2007), blended with
  :func:`isettorch.isp.learned.classical_gate_weight`. Rule pre-registered in
  ``docs/training_log.md#classical_gate_2026-11-28``.

* ``--gate relative`` (the low-noise gate read against the signal, ``relative_max``): as ``low``, each set at its own
  exposure and two stops under, the shipped absolute gate among the candidates. Rule pre-registered in
  ``docs/training_log.md#relative_gate_2026-11-28``; with ``--within-tolerance``, the second round's rule
  (``#relative_gate_round2_2026-11-28``: the best mean among the candidates within the tolerance).

All rules: the candidate with the highest mean gain over the sets and levels (against "none", the output without
the gate) ships if that mean is positive and no level's mean over the sets is more than 0.02 dB below "none".

    python training/fit_joint_gate.py --gate low --sets out/heldout_v5 out/heldout_stress [--out gate.json]
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from isettorch.io.images import rgb8_to_tensor  # noqa: E402
from isettorch.isp import learned  # noqa: E402
from isettorch.isp.demosaicing import mosaic  # noqa: E402
from isettorch.isp.evaluation import cpsnr, load_images, noisy_mosaic  # noqa: E402

LEVELS = (("sigma", 0.0025), ("sigma", 0.005), ("sigma", 0.01), ("sigma", 0.02), ("shot", 0.001), ("shot", 0.01))
GRID = (0.005, 0.0075, 0.01, 0.0125, 0.015, 0.02)
CLASSICAL_LEVELS = (("sigma", 0.005), ("sigma", 0.01), ("sigma", 0.02), ("sigma", 0.05), ("shot", 0.001),
                    ("shot", 0.003), ("shot", 0.01), ("shot", 0.02))
#: (sigma_start, sigma_full, weight_max) candidates of the high-noise gate
CLASSICAL_GRID = tuple((s0, s1, w) for s0 in (0.005, 0.01, 0.02, 0.03) for s1 in (0.05, 0.075, 0.1, 0.15)
                       for w in (0.5, 0.75, 1.0))
#: the detail-weighted high-noise gate's candidates (docs/training_log.md#classical_detail_gate_2026-11-30):
#: (sigma_start, sigma_full, weight_max, weight_detail, detail_r); the uniform gate shipped before that round
#: (UNIFORM_GATE: sigma_start, sigma_full, weight_max; #classical_gate_2026-11-28) is scored beside them as "shipped"
UNIFORM_GATE = (0.005, 0.075, 0.5)
DETAIL_GRID = tuple((s0, s1, wm, wd, rr) for s0 in (0.0, 0.0025, 0.005) for s1 in (0.01, 0.02, 0.04, 0.075)
                    for wm in (0.75, 0.9, 1.0) for wd in (0.0, 0.2, 0.4)
                    for rr in ((0.25, 1.0), (0.5, 1.5), (0.5, 2.5)))
#: the shipped absolute low-noise gate and the relative candidates (docs/training_log.md#relative_gate_2026-11-28)
RELATIVE_GRID = (("abs", 0.0125),) + tuple(("rel", r) for r in (0.0125, 0.025, 0.0375, 0.05, 0.075, 0.1))
RELATIVE_SCALES = (1.0, 0.25)
TOLERANCE_DB = 0.02


def _name(candidate) -> str:
    if isinstance(candidate, tuple):
        return "/".join(v if isinstance(v, str) else f"{v:g}" for v in candidate)
    return str(candidate)


def _parts(folder, levels, classical: bool, scale: float = 1.0):
    """Per level ``(key, [(truth, raw, noise, parts)])``: the parts of the output for each image of ``folder``:
    ``nf`` (the guarded noise-free network), ``joint`` (the guarded joint network without its gates), with
    ``classical`` also ``shipped_low`` (``joint`` under the shipped low-noise gate) and ``classical``. ``scale``:
    the exposure (the image times ``scale`` before the mosaic and the noise; the parts divided by it)."""
    expert = learned.load_pretrained("noise_free")
    joint = learned.load_pretrained("joint_denoise")
    saved, joint.level_gate = joint.level_gate, None  # the guarded joint network alone; blended below
    shipped_gate = learned.PRETRAINED_GATES["joint_denoise"]
    try:
        items = load_images(folder)
        for kind, v in levels:
            sigma, shot = (v, 0.0) if kind == "sigma" else (0.0, v)
            feats = learned.noise_features(shot, sigma**2).float()
            rows = []
            for i, (_, arr) in enumerate(items):
                truth = rgb8_to_tensor(arr)
                raw = noisy_mosaic(mosaic(truth * scale, "RGGB"), sigma, shot, seed=0, index=i).float()
                with torch.no_grad():
                    parts = {"nf": learned.demosaic_learned(raw, "RGGB", model=expert).double(),
                             "joint": learned.demosaic_learned(raw, "RGGB", model=joint, noise=feats).double()}
                if classical:
                    w = learned._level_gate(raw, feats, shipped_gate).reshape(-1, 1, 1, 1)
                    parts["shipped_low"] = w * parts["nf"] + (1 - w) * parts["joint"]
                    parts["classical"] = learned.classical_expert(raw.double(), feats).double()
                rows.append((truth, raw, feats, {k: v / scale for k, v in parts.items()}))
            yield f"{kind} {v:g}", rows
    finally:
        joint.level_gate = saved


def _scores(folder, levels, grid, *, base: str, expert: str, weight, classical: bool, scale: float = 1.0) -> dict:
    """Per level, the mean CPSNR of the part ``base`` ("none") and of ``w expert + (1 - w) base`` with ``w =
    weight(raw, noise, candidate)`` for each candidate of ``grid``."""
    out = {}
    for key, rows in _parts(folder, levels, classical=classical, scale=scale):
        per = {"none": []} | {_name(m): [] for m in grid}
        for truth, raw, feats, p in rows:
            per["none"].append(cpsnr(p[base].clamp(0, 1), truth, 10)[0].item())
            for m in grid:
                w = weight(raw, feats, m).reshape(-1, 1, 1, 1)
                y = w * p[expert] + (1 - w) * p[base]
                per[_name(m)].append(cpsnr(y.clamp(0, 1), truth, 10)[0].item())
        out[key] = {k: float(np.mean(s)) for k, s in per.items()}
    return out


def scores(folder, levels=LEVELS, grid=GRID) -> dict:
    """``{"<kind> <value>": {"none": dB, "<sigma_max>": dB, ...}}``: mean CPSNR of the bare joint network ("none")
    and of each low-noise gate on the images of ``folder``."""
    return _scores(folder, levels, grid, base="joint", expert="nf", weight=learned.level_gate_weight,
                   classical=False)


def scores_classical(folder, levels=CLASSICAL_LEVELS, grid=CLASSICAL_GRID) -> dict:
    """``{"<kind> <value>": {"none": dB, "<start>/<full>/<weight>": dB, ...}}``: mean CPSNR of the joint network
    under its shipped low-noise gate ("none") and with each high-noise gate on top, on the images of ``folder``."""
    return _scores(folder, levels, grid, base="shipped_low", expert="classical", classical=True,
                   weight=lambda raw, feats, m: learned.classical_gate_weight(raw, feats, *m))


def scores_relative(folder, scale: float, levels=LEVELS, grid=RELATIVE_GRID) -> dict:
    """``{"<kind> <value>": {"none": dB, "abs/<sigma_max>": dB, "rel/<r_max>": dB, ...}}``: mean CPSNR of the bare
    joint network ("none") and of each absolute or relative low-noise gate, the images at exposure ``scale``."""
    def weight(raw, feats, m):
        return (learned.level_gate_weight(raw, feats, m[1]) if m[0] == "abs"
                else learned.level_gate_weight(raw, feats, relative_max=m[1]))

    return _scores(folder, levels, grid, base="joint", expert="nf", weight=weight, classical=False, scale=scale)


def scores_detail(folder, levels=CLASSICAL_LEVELS, grid=DETAIL_GRID) -> dict:
    """``{"<kind> <value>": {"none": dB, "shipped": dB, "<s0>/<s1>/<wm>/<wd>/<r0>,<r1>": dB, ...}}``: mean CPSNR of
    the joint network under its shipped low-noise gate ("none"), with the uniform high-noise gate the round compared
    against (``UNIFORM_GATE``, "shipped") and with each detail-weighted gate
    (:func:`isettorch.isp.learned.classical_detail_weight`, on the mean of the two estimates, as
    :func:`isettorch.isp.learned.demosaic_learned` computes it)."""
    factors = sorted({m[2:] for m in grid})
    out = {}
    for key, rows in _parts(folder, levels, classical=True):
        per = {"none": [], "shipped": []} | {_detail_name(m): [] for m in grid}
        for truth, raw, feats, p in rows:
            base, expert = p["shipped_low"], p["classical"]

            def score(w, expert=expert, base=base, truth=truth):
                return cpsnr((w * expert + (1 - w) * base).clamp(0, 1), truth, 10)[0].item()

            per["none"].append(cpsnr(base.clamp(0, 1), truth, 10)[0].item())
            per["shipped"].append(score(learned.classical_gate_weight(raw, feats, *UNIFORM_GATE).item()))
            maps = {f: learned.classical_detail_weight(0.5 * (expert + base), feats, *f).double() for f in factors}
            for m in grid:
                ramp = learned.classical_gate_weight(raw, feats, m[0], m[1], 1.0).item()
                per[_detail_name(m)].append(score(ramp * maps[m[2:]]) if ramp > 0 else per["none"][-1])
        out[key] = {k: float(np.mean(s)) for k, s in per.items()}
    return out


def _detail_name(m) -> str:
    return "/".join(f"{v:g}" for v in m[:4]) + "/" + ",".join(f"{v:g}" for v in m[4])


def choose_detail(photos: dict, synthetic: dict, grid=DETAIL_GRID, tolerance_db: float = TOLERANCE_DB,
                  synthetic_tolerance_db: float = 0.1, margin_db: float = 0.05) -> dict:
    """The detail gate's rule (``docs/training_log.md#classical_detail_gate_2026-11-30``) on ``photos``
    (``scores_detail`` of the selection photographs) and ``synthetic`` (``{set: scores_detail(set)}``): a candidate
    is eligible if no level's mean on the photographs is more than ``tolerance_db`` below the shipped gate's and its
    mean over the synthetic sets and levels is at most ``synthetic_tolerance_db`` below the shipped gate's; the
    eligible candidate with the highest mean on the photographs ships if that mean is at least ``margin_db`` above
    the shipped gate's."""
    names = [_detail_name(m) for m in grid]
    levels = list(photos)
    gain = {n: {lv: photos[lv][n] - photos[lv]["none"] for lv in levels} for n in names + ["shipped"]}
    mean = {n: float(np.mean(list(g.values()))) for n, g in gain.items()}
    syn = {n: float(np.mean([s[lv][n] - s[lv]["shipped"] for s in synthetic.values() for lv in s]))
           for n in names}
    eligible = [n for n in names if syn[n] >= -synthetic_tolerance_db
                and all(gain[n][lv] >= gain["shipped"][lv] - tolerance_db for lv in levels)]
    best = max(eligible, key=mean.get) if eligible else None
    ships = best is not None and mean[best] >= mean["shipped"] + margin_db
    return {"gain_db": gain, "mean_gain_db": mean, "synthetic_vs_shipped_db": syn, "eligible": eligible,
            "best": best, "ships": bool(ships), "candidate": dict(zip(names, grid)).get(best)}


def _choose(by_set: dict, grid, tolerance_db: float) -> dict:
    sets = list(by_set)
    levels = list(by_set[sets[0]])
    names = [_name(m) for m in grid]
    gain = {n: {lv: float(np.mean([by_set[s][lv][n] - by_set[s][lv]["none"] for s in sets])) for lv in levels}
            for n in names}
    mean = {n: float(np.mean(list(g.values()))) for n, g in gain.items()}
    best = max(mean, key=mean.get)
    ships = mean[best] > 0 and min(gain[best].values()) >= -tolerance_db
    return {"gain_db": gain, "mean_gain_db": mean, "best": best, "ships": bool(ships),
            "candidate": dict(zip(names, grid))[best]}


def choose(by_set: dict, grid=GRID, tolerance_db: float = TOLERANCE_DB) -> dict:
    """The low-noise gate's rule on ``{set: scores(set)}``: per level the mean over the sets of each gate's gain over
    the bare joint network; the best mean gain's ``sigma_max``, and whether it ships."""
    out = _choose(by_set, grid, tolerance_db)
    return {k: out[k] for k in ("gain_db", "mean_gain_db", "ships")} | {"sigma_max": float(out["candidate"])}


def choose_classical(by_set: dict, grid=CLASSICAL_GRID, tolerance_db: float = TOLERANCE_DB) -> dict:
    """The high-noise gate's rule on ``{set: scores_classical(set)}``: the best mean gain's ``(sigma_start,
    sigma_full, weight_max)`` and whether it ships."""
    out = _choose(by_set, grid, tolerance_db)
    s0, s1, w = out["candidate"]
    return {k: out[k] for k in ("gain_db", "mean_gain_db", "ships")} | {
        "sigma_start": s0, "sigma_full": s1, "weight_max": w}


def choose_relative(by_set: dict, grid=RELATIVE_GRID, tolerance_db: float = TOLERANCE_DB, *,
                    within_tolerance: bool = False) -> dict:
    """The relative gate's rule on ``{set-exposure: scores_relative(...)}``: the best mean gain's candidate (``kind``
    "abs" or "rel", ``value``), and whether it ships (a relative candidate within the tolerance). With
    ``within_tolerance`` (the second round's rule), the best mean among the candidates within the tolerance, which
    ships if it is relative and its mean is above the shipped absolute gate's."""
    out = _choose(by_set, grid, tolerance_db)
    result = {k: out[k] for k in ("gain_db", "mean_gain_db")}
    if not within_tolerance:
        kind, value = out["candidate"]
        return result | {"kind": kind, "value": value, "ships": bool(out["ships"] and kind == "rel")}
    ok = [m for m in grid if min(out["gain_db"][_name(m)].values()) >= -tolerance_db]
    if not ok:
        return result | {"kind": None, "value": None, "ships": False}
    kind, value = max(ok, key=lambda m: out["mean_gain_db"][_name(m)])
    shipped = out["mean_gain_db"][_name(grid[0])]
    return result | {"kind": kind, "value": value,
                     "ships": bool(kind == "rel" and out["mean_gain_db"][_name((kind, value))] > shipped)}


def _print_ranked(decision: dict, names, first=(), extra=None) -> None:
    """One line per candidate: its gain at each level and its mean gain; ``first`` then the best 12 of ``names`` by
    mean gain; ``extra``: ``(label, {name: dB})``, a last column where a candidate has it."""
    mean = decision["mean_gain_db"]
    for m in [*first, *sorted(names, key=mean.get, reverse=True)[:12]]:
        column = "" if extra is None or m not in extra[1] else f" | {extra[0]} {extra[1][m]:+.3f}"
        print(f"{m}: " + " ".join(f"{lv} {d:+.3f}" for lv, d in decision["gain_db"][m].items())
              + f" | mean {mean[m]:+.3f}" + column)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--gate", choices=("low", "classical", "relative", "classical_detail"), default="low")
    p.add_argument("--photos", default=None, help="classical_detail: the selection photographs' folder")
    p.add_argument("--sets", nargs="+", required=True, help="held-out synthetic image folders")
    p.add_argument("--within-tolerance", action="store_true",
                   help="relative: the second round's rule (the best mean among the candidates within the tolerance)")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", default=None, help="write the scores and the decision (JSON) here")
    args = p.parse_args(argv)
    from training import common

    for flag, folder in [("--sets", s) for s in args.sets] + ([("--photos", args.photos)] if args.photos else []):
        try:  # a gate is fitted on these: never on a test set
            common.refuse_test_images(folder, flag)
        except ValueError as err:
            p.error(str(err))
    torch.set_num_threads(args.threads)
    if args.gate == "classical_detail":
        if not args.photos:
            p.error("--photos: required with --gate classical_detail")
        photos = scores_detail(args.photos)
        synthetic = {s: scores_detail(s) for s in args.sets}
        decision = choose_detail(photos, synthetic)
        _print_ranked(decision, decision["eligible"], first=["shipped"],
                      extra=("synthetic vs shipped", decision["synthetic_vs_shipped_db"]))
        print(f"eligible {len(decision['eligible'])} of {len(DETAIL_GRID)}; best {decision['best']}, "
              f"ships: {decision['ships']}")
        if args.out:
            Path(args.out).write_text(json.dumps({"photos": photos, "synthetic": synthetic, **decision}, indent=1))
        return 0
    if args.gate == "relative":
        by_set = {f"{s} x{k:g}": scores_relative(s, k) for s in args.sets for k in RELATIVE_SCALES}
        rule = functools.partial(choose_relative, within_tolerance=args.within_tolerance)
    else:
        score, rule = (scores, choose) if args.gate == "low" else (scores_classical, choose_classical)
        by_set = {s: score(s) for s in args.sets}
    decision = rule(by_set)
    _print_ranked(decision, decision["mean_gain_db"])
    chosen = {k: v for k, v in decision.items() if k not in ("gain_db", "mean_gain_db", "ships")}
    print(f"chosen {chosen}, ships: {decision['ships']}")
    if args.out:
        Path(args.out).write_text(json.dumps({"scores": by_set, **decision}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
