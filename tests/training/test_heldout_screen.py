"""training/heldout_screen.py: the shipping rule on two tiny held-out sets, with the shipped network against a copy
whose output head is scaled down (a worse network)."""

import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from isettorch.isp.evaluation import evaluate_demosaic, load_demosaic_model  # noqa: E402
from training import heldout_screen  # noqa: E402

SHIPPED = ROOT / "isettorch" / "assets" / "demosaic_learned.pt"


def test_screen_rule_and_scores(tmp_path, tiny_heldout_sets, damaged_shipped):
    sets, worse = tiny_heldout_sets, damaged_shipped
    res = heldout_screen.screen(str(worse), str(SHIPPED), sets)
    assert res["decision"] == "candidate"  # the shipped network beats its damaged copy on every set
    net = load_demosaic_model(SHIPPED)
    means = [evaluate_demosaic(s, "learned", "RGGB", 10, model=net)["mean_cpsnr"] for s in sets]
    assert res["candidate"]["score"] == pytest.approx(sum(means) / 2, abs=1e-9)
    assert res["candidate"][sets[0]]["mean"] > res["incumbent"][sets[0]]["mean"] + 0.5
    assert heldout_screen.screen(str(SHIPPED), str(worse), sets)["decision"] == "incumbent"
    out = tmp_path / "res.json"
    assert heldout_screen.main(["--incumbent", str(SHIPPED), "--candidate", str(SHIPPED), "--sets", *sets,
                                "--out", str(out)]) == 0
    assert json.loads(out.read_text())["decision"] == "incumbent"  # a tie does not ship: the score must beat it
    with pytest.raises(ValueError, match="sets"):
        heldout_screen.screen(str(SHIPPED), str(SHIPPED), [])
    # run_rule, a run's pre-registered screen: its own candidate and result file, or with --candidate a dry run
    # that scores the given checkpoint and writes the dry-run file instead
    rule_out, dry_out = tmp_path / "rule.json", tmp_path / "dry.json"
    assert heldout_screen.run_rule(str(SHIPPED), str(worse), sets[:1], str(rule_out), str(dry_out), argv=[]) == 0
    assert json.loads(rule_out.read_text())["decision"] == "incumbent" and not dry_out.exists()
    assert heldout_screen.run_rule(str(worse), str(worse), sets[:1], str(rule_out), str(dry_out),
                                   argv=["--candidate", str(SHIPPED)]) == 0
    dry = json.loads(dry_out.read_text())
    assert dry["decision"] == "candidate" and dry["candidate"]["path"] == str(SHIPPED)
    assert json.loads(rule_out.read_text())["decision"] == "incumbent"  # the rule's own file is left alone


def test_passes_rule_boundaries():
    """The rule on hand-made rows: the score must beat the incumbent's, a set may fall by the tolerance and no more,
    and one scene below MHC fails it."""
    sets = ["a", "b"]

    def row(a, b, below=0):
        return {"a": {"mean": a, "below_mhc": below}, "b": {"mean": b, "below_mhc": 0}, "score": (a + b) / 2}

    inc = row(40.0, 36.0)
    assert heldout_screen.passes(row(40.5, 35.95), inc, sets)  # +0.5 / -0.05: inside the guard
    assert not heldout_screen.passes(row(40.5, 35.9), inc, sets)  # -0.1 on one set
    assert heldout_screen.passes(row(40.5, 35.9), inc, sets, tolerance_db=0.1)
    assert not heldout_screen.passes(row(40.0, 36.0), inc, sets)  # a tie does not ship
    assert not heldout_screen.passes(row(40.5, 36.5, below=1), inc, sets)  # a scene below MHC


def test_registry_matches_the_committed_records():
    """Every registered screen has its committed record; the record scored the registered checkpoints on the
    registered sets, and the rule (:func:`passes`) on the record's own numbers gives the record's decision."""
    assert set(heldout_screen.RUNS) >= {"distill4_2026-11-27", "specular_2026-11-27", "distill5_2026-11-27"}
    for run, entry in heldout_screen.RUNS.items():
        record = json.loads((ROOT / heldout_screen.result_path(run)).read_text())
        inc, cand = entry.get("labels", ("incumbent", "candidate"))
        sets = entry["sets"]
        assert set(sets) <= set(heldout_screen.HELDOUT), run
        if entry.get("kind") == "best_of":  # {set: {name: row}}, MHC's row among them
            assert all(set(record[s]) == {"malvar2004", *entry["candidate"]} for s in sets), run
            assert record["decision"] == heldout_screen.best_of_decision(record, entry["incumbent"], sets) != \
                entry["incumbent"]
            continue
        if entry.get("kind") == "photos":  # the two on the stress set's photographs, the higher mean ships
            assert all(record[r]["mean"] == pytest.approx(sum(record[r]["per_image"].values()) / 8)
                       for r in ("incumbent", "candidate"))
            ships = record["candidate"]["mean"] > record["incumbent"]["mean"]
            assert record["decision"] == ("candidate" if ships else "incumbent"), run
            assert record["candidate"]["path"] == entry["candidate"]
            continue
        if entry.get("kind") == "validation":  # two rows on the run's validation set, the higher ships
            assert record["incumbent"]["path"] == entry["incumbent"] and record["candidate"]["path"] == \
                entry["candidate"]
            ships = record["candidate"]["val_cpsnr"] > record["incumbent"]["val_cpsnr"]
            assert record["decision"] == ("candidate" if ships else "incumbent"), run
            continue
        if entry.get("kind") == "interpolation":  # W(alpha) rows, each against the incumbent
            assert record["incumbent"]["path"] == entry["incumbent"]
            alphas = [k for k in record if k.startswith("a")]
            assert len(alphas) == 9 and all(record[a]["passes"] == heldout_screen.passes(record[a],
                                                                                           record["incumbent"], sets)
                                            for a in alphas)
            passing = [a for a in alphas if record[a]["passes"]]
            assert record["decision"] == max(passing, key=lambda a: record[a]["score"]), run
            continue
        for label, path in ((inc, entry["incumbent"]), (cand, entry["candidate"])):
            assert sorted(k for k in record[label] if k.startswith("out/")) == sorted(sets), run
            assert record[label].get("path", path) == path, run
            assert record[label]["score"] == pytest.approx(sum(record[label][s]["mean"] for s in sets) / len(sets))
        ships = heldout_screen.passes(record[cand], record[inc], sets)
        assert record["decision"] == (cand if ships else inc), run


def test_registered_screen_dry_run(tmp_path, tiny_heldout_sets, damaged_shipped, capsys):
    """``heldout_screen.py RUN --incumbent --candidate --sets``: a dry run of the run's rule on other checkpoints and
    sets, written with the record's row names (the first screen named its rows stage3 / dye)."""
    sets, worse = tiny_heldout_sets, damaged_shipped
    out = tmp_path / "dry.json"
    assert heldout_screen.main(["dye_2026-11-26", "--incumbent", str(worse), "--candidate", str(SHIPPED),
                                "--sets", *sets, "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    direct = heldout_screen.screen(str(worse), str(SHIPPED), sets)
    assert res["decision"] == "dye" and res["dye"]["score"] == pytest.approx(direct["candidate"]["score"], abs=1e-9)
    assert res["stage3"]["path"] == str(worse)
    assert "ship: candidate" in capsys.readouterr().out
    # the distance to a record: zero against itself, the shift against a shifted copy
    rows = {"incumbent": res["stage3"], "candidate": res["dye"]}
    assert heldout_screen.compare_to_record(rows, rows, sets) == {"incumbent": 0.0, "candidate": 0.0}
    shifted = json.loads(json.dumps(rows))
    name = next(iter(shifted["candidate"][sets[1]]["per_image"]))
    shifted["candidate"][sets[1]]["per_image"][name] += 0.25
    assert heldout_screen.compare_to_record(rows, shifted, sets)["candidate"] == pytest.approx(0.25)
    # the stage-4/5 screen's rule (best of several candidates) on the same sets
    assert heldout_screen.main(["natural_v5_stage5_2026-11-26", "--incumbent", str(worse), "--candidate",
                                str(SHIPPED), "--sets", *sets, "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["decision"] == "candidate" and set(res[sets[0]]) == {"malvar2004", "stage3", "candidate"}
    assert res[sets[1]]["candidate"]["mean"] == pytest.approx(direct["candidate"][sets[1]]["mean"], abs=1e-9)
    with pytest.raises(ValueError, match="run: expected one of"):
        heldout_screen.main(["no_such_run"])
    with pytest.raises(ValueError, match="is not one of the registered sets"):
        heldout_screen.make_sets([str(tmp_path / "missing")])


def test_screen_under_the_shipped_guard(tiny_heldout_sets):
    """``guard``: both networks scored under a shipped variant's guard, whatever their checkpoints record: the shipped
    checkpoint (no guard in its config) then scores exactly what the registered ``learned`` method scores."""
    sets = tiny_heldout_sets[:1]
    res = heldout_screen.screen(str(SHIPPED), str(SHIPPED), sets, guard="noise_free")
    shipped = evaluate_demosaic(sets[0], "learned", "RGGB", 10)["mean_cpsnr"]
    bare = evaluate_demosaic(sets[0], "learned", "RGGB", 10, model=load_demosaic_model(SHIPPED))["mean_cpsnr"]
    assert res["candidate"][sets[0]]["mean"] == pytest.approx(shipped, abs=1e-9)
    assert res["candidate"]["guard"] == "noise_free" and abs(shipped - bare) > 1e-3


def test_validation_screen(tmp_path):
    """The joint models' rule: both checkpoints on a training config's validation set (here a small noisy one), under a
    shipped guard; the shipped joint model beats a copy whose head is scaled down, and a tie does not ship."""
    import torch

    from isettorch.isp.learned import PRETRAINED

    cfg = {"seed": 3, "net": {"channels": 64, "depth": 13, "residual": True, "noise_inputs": 2},
           "data": {"source": "natural", "scene_size": 32, "patch": 32, "batch": 4, "pool": 4, "refresh": 4},
           "noise": {"enabled": True}, "val": {"images": 4, "size": 32}}
    path = tmp_path / "cfg.yaml"
    path.write_text(json.dumps(cfg))
    ck = torch.load(PRETRAINED["joint_denoise"], weights_only=True)
    ck["model"] = {k: v * 0.5 if k.startswith("head") else v for k, v in ck["model"].items()}
    worse = tmp_path / "worse.pt"
    torch.save(ck, worse)
    res = heldout_screen.validation_screen(str(path), str(worse), str(PRETRAINED["joint_denoise"]), "joint_denoise")
    assert res["decision"] == "candidate" and res["candidate"]["guard"] == "joint_denoise"
    assert res["candidate"]["val_cpsnr"] > res["incumbent"]["val_cpsnr"]
    tie = heldout_screen.validation_screen(str(path), str(worse), str(worse), "joint_denoise")
    assert tie["decision"] == "incumbent"


def test_photos_screen_and_its_registered_dry_run(tmp_path, capsys):
    """The photographs rule (the tiny network's distillation step): every stress photograph scored for both
    checkpoints under the shipped guard, Menon and MHC beside them; a tie does not ship, and a registered run with
    another candidate is a dry run that leaves the record alone."""
    from isettorch.isp.learned import PRETRAINED

    tiny = str(PRETRAINED["tiny"])
    res = heldout_screen.photos_screen(tiny, tiny, "tiny", size=64)
    from training import stress_set

    assert set(res["candidate"]["per_image"]) == set(stress_set.PHOTOS)
    assert res["candidate"]["mean"] == res["incumbent"]["mean"] and res["decision"] == "incumbent"
    assert {"menon2007", "malvar2004"} <= set(res) and res["candidate"]["guard"] == "tiny"
    out = tmp_path / "dry.json"
    record = (ROOT / heldout_screen.result_path("tiny_distill_2026-11-27")).read_text()
    assert heldout_screen.main(["tiny_distill_2026-11-27", "--incumbent", tiny, "--candidate", tiny,
                                "--out", str(out)]) == 0
    assert json.loads(out.read_text())["decision"] == "incumbent" and "ship: incumbent" in capsys.readouterr().out
    assert (ROOT / heldout_screen.result_path("tiny_distill_2026-11-27")).read_text() == record


def test_joint_gate_rule_picks_the_best_mean_and_respects_the_tolerance():
    from training.fit_joint_gate import choose

    def level(none, **gates):
        return {"none": none, **{k.replace("g", "0."): v for k, v in gates.items()}}

    # two sets, two levels; gate 0.01: +0.3 / -0.01 (mean +0.145); gate 0.02: +0.5 / -0.05 (mean +0.225, but one level
    # drops 0.05 dB: over the 0.02 dB tolerance)
    by_set = {s: {"sigma 0.005": level(30.0, g01=30.3, g02=30.5), "shot 0.001": level(20.0, g01=19.99, g02=19.95)}
              for s in ("a", "b")}
    out = choose(by_set, grid=(0.01, 0.02))
    assert out["sigma_max"] == 0.02 and not out["ships"]
    assert abs(out["mean_gain_db"]["0.01"] - 0.145) < 1e-12 and abs(out["mean_gain_db"]["0.02"] - 0.225) < 1e-12
    out = choose(by_set, grid=(0.01,))
    assert out["sigma_max"] == 0.01 and out["ships"]


def test_relative_gate_rules():
    """The relative gate's two rules (docs/training_log.md#relative_gate_2026-11-28, #relative_gate_round2_...):
    the first takes the best mean and ships it only if it is relative and within the 0.02 dB tolerance; the second
    takes the best mean among the candidates within the tolerance and ships it if it is relative and above the
    shipped absolute gate."""
    from training.fit_joint_gate import choose_relative

    grid = (("abs", 0.0125), ("rel", 0.025), ("rel", 0.05))
    # gains over "none" at two levels: abs +0.10 / 0.00; rel 0.025 +0.15 / -0.01; rel 0.05 +0.30 / -0.05
    by_set = {s: {"sigma 0.005": {"none": 30.0, "abs/0.0125": 30.1, "rel/0.025": 30.15, "rel/0.05": 30.3},
                  "shot 0.001": {"none": 20.0, "abs/0.0125": 20.0, "rel/0.025": 19.99, "rel/0.05": 19.95}}
              for s in ("a x1", "a x0.25")}
    first = choose_relative(by_set, grid)
    assert (first["kind"], first["value"], first["ships"]) == ("rel", 0.05, False)
    second = choose_relative(by_set, grid, within_tolerance=True)
    assert (second["kind"], second["value"], second["ships"]) == ("rel", 0.025, True)
    # the shipped gate better than every relative candidate within the tolerance: nothing ships
    for s in by_set:
        by_set[s]["sigma 0.005"]["abs/0.0125"] = 30.2
    second = choose_relative(by_set, grid, within_tolerance=True)
    assert (second["kind"], second["ships"]) == ("abs", False)


def test_detail_gate_rule():
    """The detail-weighted gate's rule (docs/training_log.md#classical_detail_gate_2026-11-30): eligible if no level
    on the photographs falls more than 0.02 dB below the uniform gate's gain and the synthetic sets' mean is at most
    0.1 dB below it; the eligible candidate with the best mean on the photographs ships if it is 0.05 dB above the
    uniform gate."""
    from training.fit_joint_gate import choose_detail

    grid = ((0.0, 0.01, 1.0, 0.2, (0.25, 1.0)), (0.0, 0.02, 1.0, 0.2, (0.25, 1.0)), (0.005, 0.01, 0.9, 0.0, (0.5, 1.5)))
    a, b, c = "0/0.01/1/0.2/0.25,1", "0/0.02/1/0.2/0.25,1", "0.005/0.01/0.9/0/0.5,1.5"
    # photographs, gains over "none": shipped +0.2 / +0.5; a +0.6 / +1.0 (best); b +0.3 / +0.6; c +0.19 / +1.6
    photos = {"sigma 0.01": {"none": 30.0, "shipped": 30.2, a: 30.6, b: 30.3, c: 30.19},
              "shot 0.01": {"none": 25.0, "shipped": 25.5, a: 26.0, b: 25.6, c: 26.6}}
    # synthetic: a 0.2 dB below the shipped gate on average (not eligible), b and c level with it
    synthetic = {"v5": {"sigma 0.01": {"none": 31.0, "shipped": 31.2, a: 31.0, b: 31.2, c: 31.2},
                        "shot 0.01": {"none": 27.0, "shipped": 27.2, a: 27.0, b: 27.2, c: 27.2}}}
    out = choose_detail(photos, synthetic, grid)
    # c has the best photographs' mean (+0.895) and passes the 0.02 dB tolerance (0.01 below at sigma 0.01)
    assert out["eligible"] == [b, c] and out["best"] == c and out["ships"]
    photos["sigma 0.01"][c] = 30.17  # now 0.03 dB below the shipped gain at that level: not eligible
    out = choose_detail(photos, synthetic, grid)
    assert out["eligible"] == [b] and out["best"] == b and out["ships"]  # b: mean +0.45 vs shipped +0.35
    photos["sigma 0.01"][b], photos["shot 0.01"][b] = 30.25, 25.5  # b's mean +0.375, under the shipped +0.35 plus
    # the 0.05 margin (and within the level tolerance): nothing ships
    out = choose_detail(photos, synthetic, grid)
    assert out["best"] == b and not out["ships"]
