"""train_demosaic.py with ``data.source: camera_pairs``: RGGB crops of every Bayer order, the noise-input mapping
against the sensor's actual noise, seed-only batches, finite loss and exact resume."""

import csv
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from isettorch.sensor import CFA  # noqa: E402
from training import common, train_demosaic  # noqa: E402

SMOKE = ROOT / "configs" / "train" / "demosaic_camera_pairs_smoke.yaml"


@pytest.mark.parametrize("pattern,offset", [("RGGB", (0, 0)), ("GRBG", (0, 1)), ("GBRG", (1, 0)), ("BGGR", (1, 1))])
def test_rggb_offset(pattern, offset):
    assert train_demosaic.rggb_offset(CFA(pattern).index_map) == offset
    with pytest.raises(ValueError, match="cfa"):
        train_demosaic.rggb_offset(torch.tensor([[0, 1], [2, 1]]))


def test_non_bayer_patterns_rejected():
    cfg = common.load_config(SMOKE)
    cfg["data"]["camera"] = {"cfa_patterns": ["RGGB", "RGBW"]}
    with pytest.raises(ValueError, match="cfa_patterns"):
        train_demosaic.make_sampler(cfg)


def test_camera_pair_batches_rggb_and_seed_only():
    cfg = common.load_config(SMOKE)
    cfg["noise"] = {"enabled": False}  # noise-free input: mosaicking camera_rgb must give the raw exactly
    src = train_demosaic.make_sampler(cfg)
    raw, rgb, feats = train_demosaic.make_batch(src, cfg, 7, 4)
    assert feats is None and raw.shape == (4, 1, 16, 16) and rgb.shape == (4, 3, 16, 16)
    pats = {tuple(src.ds.get_batch(src.indices(7, 4))["meta"]["cfa"][i].flatten().tolist()) for i in range(4)}
    assert len(pats) > 1  # several Bayer orders drawn, all cropped to RGGB below
    torch.testing.assert_close(raw, train_demosaic.mosaic_rggb(rgb), rtol=0, atol=1e-6)
    again = train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 7, 4)
    other = train_demosaic.make_batch(src, cfg, 8, 4)
    assert torch.equal(raw, again[0]) and torch.equal(rgb, again[1])
    assert not torch.equal(rgb, other[1])
    # validation items come from another dataset seed
    val = train_demosaic.make_sampler(cfg, train_demosaic.VAL_SEED_OFFSET)
    assert not torch.equal(val.batch(7, 4)[1], rgb)


def test_noise_inputs_match_sensor_noise():
    # (sqrt(a) 10, sqrt(b) 100) from the metadata; a x + b (+ PRNU (s x)^2, which the two noise planes leave out)
    # must predict the variance of raw - noise_free_raw (Poisson-Gaussian model, Foi et al. 2008)
    cfg = common.load_config(SMOKE)
    cfg["data"]["patch"] = 64
    src = train_demosaic.make_sampler(cfg)
    b = src.ds.get_batch(src.indices(4, 2))
    raw, _, feats = train_demosaic.pair_batch(b, 64, True)
    a, f = b["meta"]["noise_gain"], b["meta"]["noise_floor_var"]
    torch.testing.assert_close(feats, torch.stack([a.sqrt() * 10, f.sqrt() * 100], 1).float())
    nf = b["noise_free_raw"].double()
    ok = nf < 0.95  # away from clipping at white
    resid = b["raw"].double() - nf
    prnu = b["meta"]["prnu_sigma_percent"].double() / 100
    for i in range(2):
        m = ok[i]
        x = nf[i][m]
        measured, model = resid[i][m].var(), (a[i] * x + f[i] + (prnu[i] * x) ** 2).mean()
        assert float(measured / model) == pytest.approx(1.0, abs=0.06)


def test_smoke_training_resume(resume_is_exact):
    straight = resume_is_exact(["--config", str(SMOKE), "--no-progress", "--threads", "1", "--steps", "4"])
    b = torch.load(straight / "last.pt", map_location="cpu", weights_only=True)
    rows = list(csv.DictReader(open(straight / "history.csv")))
    assert all(np.isfinite(float(r["train_loss"])) and float(r["val_cpsnr"]) > 10 for r in rows)
    assert b["model"]["head.weight"].abs().sum() > 0


def test_eval_camera_pairs_untrained_net_is_mhc():
    # a DemosaicNet with its zero-initialised head outputs exactly MHC, so both must score the same on held-out items
    from isettorch.isp.learned import DemosaicNet
    from training import eval_camera_pairs

    cfg = common.load_config(SMOKE)
    torch.manual_seed(0)
    res = eval_camera_pairs.evaluate(cfg, {"zero": DemosaicNet(8, 2, noise_inputs=2)}, items=3, size=24, crop=2,
                                     batch=2)
    assert res["dataset_seed"] == cfg["seed"] + train_demosaic.TEST_SEED_OFFSET and res["items"] == 3
    assert res["cpsnr_db"]["zero"] == res["cpsnr_db"]["mhc"]
    assert 10 < res["cpsnr_db"]["mhc"]["mean"] < 80
