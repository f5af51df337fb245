"""training/codesign.py: the scene sources, the targets, and a tiny end-to-end run that exports a design file which
loads and evaluates."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from isettorch.design import (  # noqa: E402
    bound_patches,
    colour_bound_loss,
    evaluate_design,
    load_design,
    make_design,
)
from isettorch.sensor.filter_bank import MAX_SLOPE_PER_NM  # noqa: E402
from training import codesign  # noqa: E402


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cd_photos")
    g = np.random.default_rng(1)
    for i in range(2):
        Image.fromarray((g.random((30, 34, 3)) * 255).astype(np.uint8)).save(folder / f"p{i}.png")
    return folder


def test_sources_give_reflectances_and_the_photo_target_is_the_photo(photos):
    cam = make_design("bayer_rgb")
    cfg = codesign.merged_config({"data": {"folder": str(photos)}})
    maps, refl = codesign.source_layouts(0, 2, 16, cam, cfg, 0)
    assert maps.shape[:2] == refl.shape[:2] and maps.shape[-2:] == (16, 16) and refl.shape[-1] == 31
    assert float(refl.min()) >= 0 and float(refl.max()) <= 1  # a single light's spectra / its white
    again = codesign.source_layouts(0, 2, 16, cam, cfg, 0)
    assert torch.equal(maps, again[0]) and torch.equal(refl, again[1])  # a batch is a function of (seed, k)
    maps, refl = codesign.source_photos(3, 2, 16, cam, cfg, 0)
    # the lifted photograph's linear sRGB under D65 is the photograph (Mallett & Yuksel's basis, within 1 %)
    torch.testing.assert_close(codesign.targets(maps, refl, cam), maps, rtol=0, atol=0.011)
    maps, refl = codesign.source_natural(0, 2, 16, cam, cfg, 0)
    assert maps.shape[0] == 2 and float(refl.max()) <= 1 + 1e-6 and float(refl.min()) >= 0


def test_config_rejects_unknown_keys():
    with pytest.raises(ValueError, match="config.optim.stepz"):
        codesign.merged_config({"optim": {"stepz": 3}})
    with pytest.raises(ValueError, match="config.lux"):
        codesign.merged_config({"lux": [0]})
    with pytest.raises(ValueError, match="data.source"):
        codesign.train({"data": {"source": "nope"}, "optim": {"steps": 1}})
    # (steps 0 failed with an IndexError, -5 was blamed on design_warmup/design_until, batch 0 on a reshape)
    for edit, message in (({"optim": {"steps": 0}}, "optim.steps: expected an integer >= 1, got 0"),
                          ({"optim": {"steps": -5}}, "optim.steps: expected an integer >= 1, got -5"),
                          ({"data": {"batch": 0}}, "data.batch: expected an integer >= 1, got 0")):
        cfg = {"out": "/nonexistent/never_written", "optim": {"steps": 2}, **edit}
        cfg["optim"] = {"steps": 2, **edit.get("optim", {})}
        with pytest.raises(ValueError, match=message):
            codesign.train(cfg, quiet=True)
    # (a negative learning rate trained by gradient ascent; a loss crop of half the image gave NaN losses and still
    # wrote a design; val.batches 0 failed after the last step; a section or lux given as a number failed unnamed)
    for edit, message in (({"optim": {"lr": -1}}, r"config.optim.lr: expected a positive number, got -1"),
                          ({"optim": {"design_lr": 0}}, r"config.optim.design_lr: expected a positive number"),
                          ({"optim": {"lr": "abc"}}, r"config.optim.lr: expected a positive number, got .abc."),
                          ({"loss_crop": 100}, r"config.loss_crop: expected an integer >= 0 and < 32, got 100"),
                          ({"loss_crop": -1}, r"config.loss_crop: expected an integer >= 0"),
                          ({"val": {"batches": 0}}, r"config.val.batches: expected an integer >= 1, got 0"),
                          ({"val": {"crop": 100}}, r"config.val.crop: expected an integer >= 0 and < 32"),
                          ({"seed": "abc"}, r"config.seed: expected an integer"),
                          ({"checkpoint_every": -1}, r"config.checkpoint_every: expected an integer >= 0"),
                          ({"optim": 5}, r"config.optim: expected a mapping, got 5"),
                          ({"lux": 5}, r"config.lux: expected a list of positive light levels, got 5"),
                          ({"lux": "abc"}, r"config.lux: expected a list")):
        with pytest.raises(ValueError, match=rf"^{message}"):
            codesign.merged_config(edit)


def test_tiny_run_exports_a_manufacturable_design(tmp_path, photos):
    out = tmp_path / "run"
    record = codesign.train({"out": str(out), "threads": 1, "lux": [2, 50],
                             "design": {"filters": ["learned", "learned", "W"], "mosaic_shape": [2, 2]},
                             "camera": {"network": {"width": 4, "depth": 1}},
                             "data": {"size": 16, "batch": 2}, "optim": {"steps": 4, "design_warmup": 0.5},
                             "val": {"batches": 1, "every": 2}}, quiet=True)
    assert set(record["val_cpsnr"]) == {"2", "50"}
    for name in ("design.pt", "card.md", "history.csv", "curves.png", "filters.png", "record.json"):
        assert (out / name).is_file(), name
    cam = load_design(out / "design.pt")
    assert cam.lux_levels == [2.0, 50.0] and cam.name == "learned"
    f = cam.bank.filters
    assert bool(((f >= 0) & (f <= 1)).all())
    assert float(((f[:, 1:] - f[:, :-1]) / 10).abs().max()) <= MAX_SLOPE_PER_NM
    # the exported mosaic is the trained one's hard pattern, one filter per pixel
    rec = json.loads((out / "record.json").read_text())
    assert cam.mosaic.cell == rec["mosaic"]
    w = cam.mosaic.weights(4, 4)
    assert bool(((w == 0) | (w == 1)).all())
    res = evaluate_design(out / "design.pt", photos, crop=2)
    assert set(res["mean_cpsnr"]) == {"2", "50"} and all(np.isfinite(v) for v in res["mean_cpsnr"].values())
    assert "steps 4" in cam.card
    # the design learned after the warm-up: the filters moved from their initial values
    from isettorch.sensor.filter_bank import FilterBank
    start = FilterBank(["learned", "learned", "W"], seed=0, fixed_scale="peak").filters
    assert float((cam.bank.filters.detach() - start).abs().max()) > 1e-3


# a tiny learned design's run, checkpointed every 3 of its 6 steps (its levels a tuple: a Python config resumes as
# its YAML form does)
TINY_RUN = {"threads": 1, "lux": (2, 50), "design": {"filters": ["learned", "learned", "W"], "mosaic_shape": [2, 2]},
            "camera": {"network": {"width": 4, "depth": 1}}, "data": {"size": 16, "batch": 2},
            "optim": {"steps": 6, "design_warmup": 0.3}, "val": {"batches": 1, "every": 0}, "checkpoint_every": 3}


def _stop_at_the_first_checkpoint(monkeypatch, cfg: dict) -> None:
    """Run ``cfg`` until its first checkpoint is written, then stop it as an interrupted run stops."""
    real_save = codesign._save_checkpoint

    def save_then_stop(*args):
        real_save(*args)
        raise KeyboardInterrupt

    monkeypatch.setattr(codesign, "_save_checkpoint", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        codesign.train(cfg, quiet=True)
    monkeypatch.setattr(codesign, "_save_checkpoint", real_save)


def test_an_interrupted_run_resumes_to_the_same_design(tmp_path, monkeypatch):
    """A run stopped after its checkpoint and run again ends with the design of an uninterrupted run (weights,
    filters and mosaic logits equal), and a finished run leaves no checkpoint."""
    cfg = TINY_RUN
    whole = codesign.train({**cfg, "out": str(tmp_path / "whole")}, quiet=True)
    assert not (tmp_path / "whole" / "checkpoint.pt").exists()
    _stop_at_the_first_checkpoint(monkeypatch, {**cfg, "out": str(tmp_path / "split")})
    assert (tmp_path / "split" / "checkpoint.pt").is_file()
    split = codesign.train({**cfg, "out": str(tmp_path / "split")}, quiet=True)
    a, b = load_design(whole["path"]), load_design(split["path"])
    for (name, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        torch.testing.assert_close(x, y, rtol=0, atol=0, msg=name)
    rows = (tmp_path / "split" / "history.csv").read_text().splitlines()
    assert len(rows) == 1 + 6  # header and every step once
    _stop_at_the_first_checkpoint(monkeypatch, {**cfg, "out": str(tmp_path / "other")})
    with pytest.raises(ValueError, match=r"another config \(seed changed\)"):  # (it named no key)
        codesign.train({**cfg, "seed": 5, "out": str(tmp_path / "other")}, quiet=True)
    with pytest.raises(ValueError, match=r"another config \(optim\.lr changed\)"):
        codesign.train({**cfg, "optim": {**cfg["optim"], "lr": 0.5}, "out": str(tmp_path / "other")}, quiet=True)


def test_config_device_is_checked(tmp_path):
    with pytest.raises(ValueError, match="device: 'tpu'"):
        codesign.train({"device": "tpu", "optim": {"steps": 1}})
    # a torch.device from Python is written as its name (it failed to serialise at the first checkpoint)
    record = codesign.train({**TINY_RUN, "optim": {"steps": 2}, "checkpoint_every": 1, "device": torch.device("cpu"),
                             "out": str(tmp_path / "run")}, quiet=True)
    assert record["config"]["device"] == "cpu"


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_run_on_cuda_renders_as_the_cpu_does_and_resumes_on_the_cpu(tmp_path, monkeypatch):
    """On CUDA the design camera's noise-free capture and reconstruction equal the CPU's (TF32 off); a run trains
    there, stops after its checkpoint, resumes on the CPU and exports a design that loads and evaluates on the CPU."""
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    cam = make_design({"filters": ["learned", "learned", "W"], "mosaic_shape": [2, 2]},
                      {"network": {"width": 4, "depth": 1}}, [5.0], seed=3).eval()
    maps, refl = codesign.source_layouts(0, 2, 16, cam, codesign.merged_config({}), 0)
    with torch.no_grad():
        cpu = cam(cam.scene(maps, refl, 5.0), 5.0, noise=False)
        gpu = cam.to("cuda")(cam.scene(maps.cuda(), refl.cuda(), 5.0), 5.0, noise=False)
    assert gpu.device.type == "cuda"
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=1e-4, atol=1e-5)

    cfg = {**TINY_RUN, "val": {"batches": 1, "every": 3}, "out": str(tmp_path / "run")}
    _stop_at_the_first_checkpoint(monkeypatch, {**cfg, "device": "cuda"})
    record = codesign.train({**cfg, "device": "cpu"}, quiet=True)
    rows = (tmp_path / "run" / "history.csv").read_text().splitlines()
    assert len(rows) == 1 + 6
    assert all(math.isfinite(v) for v in record["val_cpsnr"].values())
    design = load_design(record["path"])
    assert next(design.parameters()).device.type == "cpu"
    f = design.bank.filters
    assert bool(((f >= 0) & (f <= 1)).all())


def _record_states(monkeypatch) -> dict:
    """The camera's state at every checkpoint of a run (``{step: state_dict}``), the checkpoints still written."""
    states = {}
    real_save = codesign._save_checkpoint

    def keep(path, cfg, camera, opt, sched, step, *rest):
        states[step] = {k: v.clone() for k, v in camera.state_dict().items()}
        real_save(path, cfg, camera, opt, sched, step, *rest)

    monkeypatch.setattr(codesign, "_save_checkpoint", keep)
    return states


def test_the_design_learns_only_between_warmup_and_until(tmp_path, monkeypatch):
    """optim.design_warmup / design_until: the filters and mosaic logits change only in their window of steps
    (here step 2 of 4); the networks learn throughout. And design.mosaic_init starts the mosaic from a pattern."""
    spec = {"filters": ["learned", "learned", "W"], "mosaic_init": [["W", "F0"], ["F1", "W"]]}
    assert make_design(spec).mosaic.cell == [["W", "F0"], ["F1", "W"]]
    soft = make_design({**spec, "mosaic_init_margin": 1.5}).mosaic
    assert soft.cell == [["W", "F0"], ["F1", "W"]]
    torch.testing.assert_close(soft.logits.max(0).values, torch.full((2, 2), 1.5, dtype=torch.float64))
    torch.testing.assert_close(torch.softmax(make_design(spec).mosaic.logits, 0).max(0).values,
                               torch.full((2, 2), math.exp(4) / (math.exp(4) + 2), dtype=torch.float64))
    with pytest.raises(ValueError, match="mosaic_init_margin: only with"):
        make_design({"filters": ["learned", "W"], "mosaic_init_margin": 2})
    with pytest.raises(ValueError, match="pattern_margin"):
        make_design({**spec, "mosaic_init_margin": -1})
    with pytest.raises(ValueError, match="design.mosaic_init: 'R'"):
        make_design({"filters": ["learned", "W"], "mosaic_init": [["R", "W"]]})
    with pytest.raises(ValueError, match="design_until"):
        codesign.train({"optim": {"steps": 4, "design_warmup": 0.75, "design_until": 0.5},
                        "out": str(tmp_path / "bad")}, quiet=True)
    states = _record_states(monkeypatch)
    cfg = {"threads": 1, "lux": [5], "design": spec, "camera": {"network": {"width": 4, "depth": 1}},
           "data": {"size": 16, "batch": 2}, "optim": {"steps": 4, "design_warmup": 0.25, "design_until": 0.5},
           "val": {"batches": 1, "every": 0}, "checkpoint_every": 1, "out": str(tmp_path / "run")}
    record = codesign.train(cfg, quiet=True)
    design = [k for k in states[1] if not k.startswith("networks.") and states[1][k].is_floating_point()
              and ("raw_" in k or "logits" in k)]
    assert design
    for k in design:
        assert torch.equal(states[1][k], make_design(spec).state_dict()[k]), k  # step 1: the networks only
        assert torch.equal(states[2][k], states[3][k]), k  # frozen from step 3 on
    assert any(not torch.equal(states[1][k], states[2][k]) for k in design)  # step 2 learned the design
    net = [k for k in states[1] if k.startswith("networks.") and states[1][k].is_floating_point()]
    assert any(not torch.equal(states[2][k], states[3][k]) for k in net)  # the networks learn after the freeze
    logits = [k for k in design if k.endswith("logits")]
    assert len(logits) == 1  # the exported mosaic is the frozen logits' argmax
    assert torch.equal(load_design(record["path"]).mosaic.index_map, states[2][logits[0]].argmax(0))


def test_the_design_learns_only_at_its_design_levels(tmp_path, monkeypatch):
    """optim.design_lux: the filters move only on the steps at those levels (the levels are taken in turn: step 1 at
    10 lux, step 2 at 1 lux); a level outside the run's is refused."""
    with pytest.raises(ValueError, match="optim.design_lux"):
        codesign.train({"lux": [1, 10], "optim": {"steps": 2, "design_lux": [100]}, "out": str(tmp_path / "bad")},
                       quiet=True)
    states = _record_states(monkeypatch)
    spec = {"filters": ["learned", "learned", "W"], "mosaic_init": [["W", "F0"], ["F1", "W"]]}
    cfg = {"threads": 1, "lux": [10, 1], "design": spec, "camera": {"network": {"width": 4, "depth": 1}},
           "data": {"size": 16, "batch": 2}, "optim": {"steps": 3, "design_lux": [1]},
           "val": {"batches": 1, "every": 0}, "checkpoint_every": 1, "out": str(tmp_path / "run")}
    codesign.train(cfg, quiet=True)
    filters = [k for k in states[1] if "raw_" in k]
    assert filters
    for k in filters:
        assert torch.equal(states[1][k], make_design(spec).state_dict()[k]), k  # step 1, 10 lux: unchanged
    assert any(not torch.equal(states[1][k], states[2][k]) for k in filters)  # step 2, 1 lux: learned


def test_predesign_lowers_the_colour_bound_and_the_run_keeps_its_filters(tmp_path, monkeypatch):
    """predesign: Adam on the noise-limited colour estimate lowers it, the filters stay manufacturable, a design
    fixed for training (design_until 0) exports exactly the predesigned filters, and a bank without learned filters
    is refused."""
    from isettorch.sensor.filter_bank import check_manufacturable

    spec = {"filters": ["learned", "learned", "learned"], "mosaic_init": [["F1", "F0"], ["F2", "F1"]]}
    cfg = codesign.merged_config({"lux": [1], "predesign": {"steps": 6, "fit_patches": 24, "test_colours": 12}})
    cam = make_design(spec, None, [1.0])
    patches = bound_patches(cam.wavelengths_nm, 24, 12, 5)
    with torch.no_grad():
        before = float(colour_bound_loss(cam.eval(), patches, [1.0], 16))
    res = codesign.predesign(cam, cfg, quiet=True)
    with torch.no_grad():
        after = float(colour_bound_loss(cam.eval(), patches, [1.0], 16))
    assert res["loss"][0] == pytest.approx(before, rel=1e-12)
    assert after < before - 0.05
    check_manufacturable(cam.bank.filters.detach(), cam.bank.wavelengths_nm)
    assert set(res["gain_db"]) == {"1"}
    # the bound's Bayer reference, recomputed here: gain = 10 log10(error_bayer / error_design)
    with torch.no_grad():
        bayer = float(colour_bound_loss(make_design("bayer_rgb").eval(), patches, [1.0], 16))
    assert res["loss"][1] == pytest.approx(after, rel=1e-12)
    assert res["gain_db"]["1"] == pytest.approx(10 / math.log(10) * (bayer - after), abs=1e-3)

    run = {"threads": 1, "lux": [1], "design": spec, "camera": {"network": {"width": 4, "depth": 1}},
           "data": {"size": 16, "batch": 2}, "optim": {"steps": 2, "design_warmup": 0.0, "design_until": 0.0},
           "val": {"batches": 1, "every": 0}, "predesign": {"steps": 6, "fit_patches": 24, "test_colours": 12},
           "out": str(tmp_path / "run")}
    record = codesign.train(run, quiet=True)
    exported = load_design(record["path"])
    torch.testing.assert_close(exported.bank.filters, cam.bank.filters.detach().to(exported.bank.filters.dtype),
                               rtol=0, atol=1e-12)
    assert exported.config["training"]["predesign"]["steps"] == 6
    # a run stopped at its checkpoint and resumed skips the predesign and keeps its record
    split = {**run, "optim": {**run["optim"], "steps": 4}, "checkpoint_every": 2, "out": str(tmp_path / "split")}
    _stop_at_the_first_checkpoint(monkeypatch, split)
    calls = []
    monkeypatch.setattr(codesign, "predesign", lambda *a, **k: calls.append(1))
    resumed = load_design(codesign.train(split, quiet=True)["path"])
    assert not calls
    assert resumed.config["training"]["predesign"] == exported.config["training"]["predesign"]
    torch.testing.assert_close(resumed.bank.filters, exported.bank.filters, rtol=0, atol=0)
    with pytest.raises(ValueError, match="predesign.steps"):
        codesign.train({**run, "design": "bayer_rgb", "out": str(tmp_path / "bayer")}, quiet=True)


def test_losses_against_colour_science():
    """``l1``: L1 in linear sRGB plus the weighted L1 in encoded sRGB; ``mse_srgb``: the squared error in encoded
    sRGB (colour-science's IEC 61966-2-1 encoding), the quantity CPSNR scores; an unknown loss is refused."""
    import colour

    g = torch.Generator().manual_seed(0)
    out, target = torch.rand(2, 3, 12, 12, generator=g, dtype=torch.float64) * 1.2, torch.rand(
        2, 3, 12, 12, generator=g, dtype=torch.float64)
    enc = [torch.from_numpy(colour.cctf_encoding(np.clip(x.numpy(), 0, 1), function="sRGB")) for x in (out, target)]
    crop = (slice(None), slice(None), slice(2, -2), slice(2, -2))
    expected_mse = float(((enc[0] - enc[1])[crop] ** 2).mean())
    assert float(codesign._loss(out, target, 2, 1.0, "mse_srgb")) == pytest.approx(expected_mse, rel=1e-9)
    expected_l1 = float((out - target)[crop].abs().mean() + 0.5 * (enc[0] - enc[1])[crop].abs().mean())
    assert float(codesign._loss(out, target, 2, 0.5, "l1")) == pytest.approx(expected_l1, rel=1e-9)
    with pytest.raises(ValueError, match="optim.loss"):
        codesign.train({"optim": {"steps": 1, "loss": "l2"}})


def test_the_photos_source_validates_on_photographs_it_does_not_train_on(monkeypatch):
    """codesign with data.source photos drew its validation crops from the training photographs (only the seed
    differed) under a card that called them held out: every fifth photograph (by name) is now validation only."""
    from training import codesign_sources

    rng = np.random.default_rng(0)
    photos = [(f"p{i}", rng.integers(0, 256, (40, 40, 3), dtype=np.uint8)) for i in range(10)]
    monkeypatch.setattr(codesign_sources.source_photos, "cache", {"/photos": photos}, raising=False)
    cfg = codesign.merged_config({"data": {"source": "photos", "folder": "/photos", "size": 32, "batch": 4}})
    cam = make_design("bayer_rgb", {}, [10.0], seed=0)
    seen = {"train": set(), "val": set()}
    for split in seen:
        for k in range(12):
            maps, _ = codesign_sources.source_photos(k, 4, 32, cam, cfg, 0, split=split)
            for crop in maps:  # which photograph each crop came from: the lifted crop's match
                seen[split].add(min(range(10), key=lambda i: _crop_distance(photos[i][1], crop)))
    assert seen["val"] == {4, 9} and seen["train"] == {0, 1, 2, 3, 5, 6, 7, 8}


def _crop_distance(photo, maps) -> float:
    """How far ``maps``' first map is from any 32 x 32 crop (or its mirror) of ``photo``'s luminance, coarsely: the
    means of the crop's quarters against the photo's."""
    lum = photo.astype(np.float64).mean(-1)
    m = maps.numpy().sum(0)
    best = math.inf
    for y in range(0, 9):
        for x in range(0, 9):
            c = lum[y:y + 32, x:x + 32]
            for cc in (c, c[:, ::-1]):
                r = np.corrcoef(cc.ravel(), m.ravel())[0, 1]
                best = min(best, 1 - r)
    return best
