"""train_demosaic.py with ``data.source: stream`` (isettorch.data.PairStream on the training device): RGGB crops
of every Bayer order made on the device, noise inputs from the stream's metadata, batches that depend only on
(seed, step, rank), and an exact resume."""

import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from training import common, train_demosaic  # noqa: E402

SMOKE = ROOT / "configs" / "train" / "demosaic_stream_smoke.yaml"


def test_stream_batches_are_rggb_crops_of_the_stream():
    cfg = common.load_config(SMOKE)
    cfg["noise"] = {"enabled": False}  # noise-free input: mosaicking camera_rgb must give the raw exactly
    src = train_demosaic.make_sampler(cfg)
    assert isinstance(src, train_demosaic.StreamSource)
    raw, rgb, feats = train_demosaic.make_batch(src, cfg, 0, 4, step=3)
    assert feats is None and raw.shape == (4, 1, 16, 16) and rgb.shape == (4, 3, 16, 16)
    torch.testing.assert_close(raw, train_demosaic.mosaic_rggb(rgb), rtol=0, atol=1e-6)
    b = src.stream.batch(3)
    # the same crops as the per-item path (rggb_offset reads each item's CFA on the host)
    ref_raw, ref_rgb, _ = train_demosaic.pair_batch(b, 16, False)
    assert torch.equal(raw, ref_raw) and torch.equal(rgb, ref_rgb)
    pats = {tuple(b["meta"]["cfa"][i].flatten().tolist()) for i in range(4)}
    assert len(pats) > 1
    again = train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 0, 4, step=3)
    assert torch.equal(raw, again[0]) and torch.equal(rgb, again[1])
    assert not torch.equal(rgb, train_demosaic.make_batch(src, cfg, 0, 4, step=4)[1])


def test_noise_features_from_stream_metadata():
    cfg = common.load_config(SMOKE)
    src = train_demosaic.make_sampler(cfg)
    _, _, feats = train_demosaic.make_batch(src, cfg, 0, 4, step=1)
    b = src.stream.batch(1)
    a, f = b["meta"]["noise_gain"], b["meta"]["noise_floor_var"]
    torch.testing.assert_close(feats, torch.stack([a.sqrt() * 10, f.sqrt() * 100], 1).float())


def test_smoke_training_resume_with_stream(resume_is_exact):
    straight = resume_is_exact(["--config", str(SMOKE), "--no-progress", "--threads", "1", "--steps", "4", "--device",
                                "cpu"])
    assert "PairStream" in (straight / "MODEL_CARD.md").read_text()
