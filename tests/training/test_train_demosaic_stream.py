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
    cfg["data"] = dict(cfg["data"], stream_chunk=1)  # step s is stream batch s (chunks: the test below)
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
    cfg["data"] = dict(cfg["data"], stream_chunk=1)
    src = train_demosaic.make_sampler(cfg)
    _, _, feats = train_demosaic.make_batch(src, cfg, 0, 4, step=1)
    b = src.stream.batch(1)
    a, f = b["meta"]["noise_gain"], b["meta"]["noise_floor_var"]
    torch.testing.assert_close(feats, torch.stack([a.sqrt() * 10, f.sqrt() * 100], 1).float())


def test_smoke_training_resume_with_stream(resume_is_exact):
    straight = resume_is_exact(["--config", str(SMOKE), "--no-progress", "--threads", "1", "--steps", "4", "--device",
                                "cpu"])
    assert "PairStream" in (straight / "MODEL_CARD.md").read_text()


def test_stream_chunks_are_slices_of_one_larger_stream_batch():
    # data.stream_chunk c: step s is slice s % c of stream batch s // c (of c x batch items), the chunk rendered once
    # for its c steps; a fresh source (a resumed run) gives the same batch for the same step; bad values raise
    import pytest

    cfg = common.load_config(SMOKE)
    cfg["noise"] = {"enabled": False}
    cfg["data"] = dict(cfg["data"], stream_chunk=3)
    src = train_demosaic.make_sampler(cfg, batch=4)
    assert src.chunk == 3 and src.stream.batch_size == 12
    ref_raw, ref_rgb, _ = train_demosaic.pair_batch(src.stream.batch(1), 16, False)  # chunk 1: steps 3, 4, 5
    calls = []
    render = src.stream.batch
    src.stream.batch = lambda k: calls.append(k) or render(k)
    for step in (3, 4, 5):
        raw, rgb, feats = train_demosaic.make_batch(src, cfg, 0, 4, step=step)
        j = step - 3
        assert torch.equal(raw, ref_raw[4 * j:4 * j + 4]) and torch.equal(rgb, ref_rgb[4 * j:4 * j + 4])
    assert calls == [1]  # one render for the chunk's three steps
    fresh = train_demosaic.make_sampler(cfg, batch=4)
    assert torch.equal(train_demosaic.make_batch(fresh, cfg, 0, 4, step=5)[1], ref_rgb[8:12])
    assert train_demosaic.make_sampler(common.load_config(SMOKE), batch=4).chunk == 4  # the CPU default
    for bad in (0, 2.5, True, "4"):
        cfg["data"]["stream_chunk"] = bad
        with pytest.raises(ValueError, match="data.stream_chunk"):
            train_demosaic.make_sampler(cfg, batch=4)


def test_stream_chunk_noise_features_follow_their_items():
    cfg = common.load_config(SMOKE)
    cfg["data"] = dict(cfg["data"], stream_chunk=2)
    src = train_demosaic.make_sampler(cfg, batch=4)
    _, _, feats = train_demosaic.make_batch(src, cfg, 0, 4, step=1)  # the second slice of stream batch 0
    b = src.stream.batch(0)
    a, f = b["meta"]["noise_gain"][4:8], b["meta"]["noise_floor_var"][4:8]
    torch.testing.assert_close(feats, torch.stack([a.sqrt() * 10, f.sqrt() * 100], 1).float())
