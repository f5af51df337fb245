"""PairStream: batches generated on a device through the Camera modules.

Distribution tests compare summary statistics of the stream with CameraPairDataset / generate_scene (the per-item
generators) by a two-sample z test: a statistic's means differ by less than 4 combined standard errors (both
samples are fixed by their seeds, so a test passes or fails deterministically; at 4 sigma an unlucky seed would
fail with probability ~6e-5 per statistic if the distributions were equal). The leaf-size law is checked with
Kolmogorov-Smirnov against its closed-form CDF.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest
import torch

from isettorch import spectral
from isettorch.data import PairStream
from isettorch.data.batched import LAYOUT_CODES, draw_layout_scenes
from isettorch.data.camera_pairs import META_KEYS, CameraPairDataset
from isettorch.data.config import SCENE_DEFAULTS, merge_config, one_thread
from isettorch.data.scenes import _luminance_weights, generate_scene

SMALL = {"height": 32, "width": 32}


def _z_close(a, b, n_sigma=4.0):
    a, b = np.asarray(a, float), np.asarray(b, float)
    se = math.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size)
    return abs(a.mean() - b.mean()) <= n_sigma * se, (a.mean(), b.mean(), se)


def test_batch_shapes_keys_units_and_repeatable():
    stream = PairStream(4, seed=3, scene=SMALL)
    batch = stream.batch(2)
    ref = CameraPairDataset(4, seed=3, scene=SMALL).get_batch([0, 1, 2, 3])
    assert set(batch) == set(ref)
    for key, v in ref.items():
        if key == "meta":
            assert set(batch["meta"]) == set(META_KEYS)
            for m, t in v.items():
                assert batch["meta"][m].shape == t.shape, m
                assert batch["meta"][m].dtype == t.dtype, m
        else:
            assert batch[key].shape == v.shape and batch[key].dtype == v.dtype and batch[key].device.type == "cpu"
    # normalised raw units: black 0, white 1
    assert float(batch["raw"].max()) <= 1.0 and float(batch["noise_free_raw"].min()) >= 0.0
    again = PairStream(4, seed=3, scene=SMALL).batch(2)
    for key in ("raw", "noise_free_raw", "camera_rgb", "xyz", "linear_srgb", "srgb"):
        assert torch.equal(batch[key], again[key]), key
    for m in META_KEYS:
        assert torch.equal(batch["meta"][m], again["meta"][m]), m
    assert batch["meta"]["index"].tolist() == [8, 9, 10, 11]
    assert not torch.equal(stream.batch(3)["raw"], batch["raw"])
    assert not batch["raw"].requires_grad
    it = iter(stream)
    assert torch.equal(next(it)["raw"], stream.batch(0)["raw"])
    assert torch.equal(next(it)["raw"], stream.batch(1)["raw"])


def test_stream_equals_camera_on_drawn_scenes(stream_equals_camera):
    """Each group's camera applied to the drawn scene with the same settings gives the stream's batch: the
    noise-free raw to float rounding, and (one group, camera_rgb only: the same projections) the noisy raw exactly
    from the same generator state."""
    stream_equals_camera(PairStream(6, seed=1, scene=SMALL, camera={"pixel_size_m": [1.4e-6, 2.8e-6]}), 0,
                         PairStream(5, seed=4, scene=SMALL, camera={"pixel_size_m": [2.0e-6]}, targets=("camera_rgb",)),
                         7)


def test_parts_render_on_threads_without_changing_the_batch(stream_equals_camera):
    """A batch drawn in parts is the same whichever number of threads renders it (bitwise: each part has its own
    generators), its parts are consecutive items each equal to the Camera on the part's drawn groups (noise-free
    raw to float rounding; the noisy raw of a one-group part bitwise from the part's own noise generator), and
    the items of the two parts differ (their generators are independent)."""
    cams = {"pixel_size_m": [1.4e-6, 2.8e-6]}
    threaded = PairStream(8, seed=6, scene=SMALL, camera=cams, parts=2, threads=2)
    assert threaded.parts == 2 and threaded._thread_count() == 2
    one = PairStream(8, seed=6, scene=SMALL, camera=cams, parts=2, threads=1)
    a, b = threaded.batch(3), one.batch(3)
    for key in ("raw", "noise_free_raw", "camera_rgb", "xyz", "srgb"):
        assert torch.equal(a[key], b[key]), key
    for m in META_KEYS:
        assert torch.equal(a["meta"][m], b["meta"][m]), m
    assert a["meta"]["index"].tolist() == list(range(24, 32))
    groups = threaded.draw(3)
    assert sorted(torch.cat([g.index for g in groups]).tolist()) == list(range(8))
    assert {g.part for g in groups} == {0, 1}
    assert all(set(g.index.tolist()) <= (set(range(4)) if g.part == 0 else set(range(4, 8))) for g in groups)
    stream_equals_camera(threaded, 3, PairStream(8, seed=2, scene=SMALL, camera={"pixel_size_m": [2.0e-6]},
                                                 targets=("camera_rgb",), parts=1), 5)
    # part 1 of a two-part stream: its one group with the part's noise generator gives its raw bitwise
    two = PairStream(8, seed=2, scene=SMALL, camera={"pixel_size_m": [2.0e-6]}, targets=("camera_rgb",), parts=2)
    (grp,) = [g for g in two.draw(5) if g.part == 1]
    with one_thread():  # (as the stream renders a CPU part)
        raw = grp.camera(grp.scene, return_intermediates=True, generator=two._generator(5, 2, 1), **grp.kwargs).raw
    got = two.batch(5)["raw"][grp.index]
    black, white = raw.levels()
    assert torch.equal((raw.data - black) / (white - black), got)
    # the two parts are independent draws, not copies
    assert not torch.equal(a["noise_free_raw"][:4], a["noise_free_raw"][4:])
    # the default on a CPU: one part per 32 items (at least one); one with a camera module
    assert [PairStream(n, scene=SMALL).parts for n in (4, 32, 63, 64, 128)] == [1, 1, 1, 2, 4]
    with pytest.raises(ValueError, match="parts"):
        PairStream(4, scene=SMALL, parts=5)
    with pytest.raises(ValueError, match="threads"):
        PairStream(4, scene=SMALL, threads=0)


FOUR_CFAS = {"cfa_patterns": ["RGGB", "GRBG", "GBRG", "BGGR"]}  # one render group per CFA: small groups


def test_batch_does_not_depend_on_the_intra_op_thread_count():
    """At 128^2 the Fourier-domain products are large enough for torch to split plain 2-D products across its
    intra-op threads, which rounds differently with their number; a batch (here one-item groups: a batch of one,
    the groups of a batch of 16, and a camera module's batch of one with gradients) is bitwise the same on 1 and 2
    threads (a one-item group's XYZ used to differ by an ulp). Gradients are not: torch's reductions split by
    thread."""
    from isettorch import Camera
    from isettorch.optics import DiffractionLimitedOptics
    from isettorch.sensor import Sensor

    n = torch.get_num_threads()
    out = {}
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            # and a camera module's one-item batch with its autograd graph (the products that keep a gradient)
            camera = Camera(DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3, learn_f_number=True),
                            Sensor(rows=128, cols=128, pixel_size_m=2.0e-6, cfa="RGGB", learnable_filters=True))
            graph = PairStream(1, seed=0, scene={"height": 128, "width": 128}, camera=camera, grad=True).batch(0)
            out[threads] = [PairStream(1, seed=0).batch(2), PairStream(16, seed=0, camera=FOUR_CFAS, parts=2,
                                                                      threads=1).batch(3),
                            {k: v.detach() for k, v in graph.items() if k != "meta"}]
    finally:
        torch.set_num_threads(n)
    assert any(g.index.numel() == 1 for g in PairStream(16, seed=0, camera=FOUR_CFAS, parts=2).draw(3))
    for a, b in zip(out[1], out[2]):
        for key in a:
            if key != "meta":
                assert torch.equal(a[key], b[key]), key


def test_iteration_renders_whole_batches_on_threads_bitwise():
    """On a CPU ``iter(stream)`` renders ``threads`` whole batches at once on worker threads (one intra-op thread
    each): the batches are bitwise ``batch(k)`` in order (with ``rank`` / ``world_size`` too, and in two parts),
    the caller's intra-op thread count is unchanged, and a stream with gradients iterates on the caller's thread."""
    n = torch.get_num_threads()
    for kw, ks in (({"threads": 2}, [0, 1, 2, 3]), ({"threads": 3, "parts": 2}, [0, 1, 2]),
                   ({"threads": 2, "rank": 1, "world_size": 3}, [1, 4, 7])):
        stream = PairStream(4, seed=5, scene=SMALL, **kw)
        assert stream._pipeline_width() == kw["threads"]
        it = iter(stream)
        got = [next(it) for _ in ks]
        assert torch.get_num_threads() == n
        it.close()
        for b, k in zip(got, ks):
            ref = stream.batch(k)
            for key in ("raw", "noise_free_raw", "camera_rgb", "srgb"):
                assert torch.equal(b[key], ref[key]), (kw, k, key)
            assert torch.equal(b["meta"]["index"], ref["meta"]["index"])
    assert PairStream(4, scene=SMALL, grad=True)._pipeline_width() == 1
    assert PairStream(4, scene=SMALL, threads=1)._pipeline_width() == 1
    # defaults: the intra-op thread count, one more from 64 items
    assert PairStream(63, scene=SMALL)._pipeline_width() == n
    assert PairStream(64, scene=SMALL)._pipeline_width() == n + 1
    # batches(start): a rank's batches from its start-th on (a resumed run)
    stream = PairStream(4, seed=5, scene=SMALL, threads=2, rank=1, world_size=3)
    it = stream.batches(2)
    for k in (7, 10):
        assert torch.equal(next(it)["raw"], stream.batch(k)["raw"])
    it.close()
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="start"):
            stream.batches(bad)


class _SlowBatches(PairStream):
    """Each whole batch but the first takes 0.5 s more, and says when it starts and ends."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.started, self.ended = [], []

    def _whole_batch(self, k):
        self.started.append(k)
        time.sleep(0.5 if k else 0.0)
        out = super()._whole_batch(k)
        self.ended.append(k)
        return out


def test_closing_the_iterator_waits_for_the_batches_it_started():
    """Closing ``iter(stream)`` returns once the batches its threads had started are rendered and drops those not
    started: none renders on after it (they had run on unseen, taking cores from what the caller did next, and a
    fork then, as a DataLoader's workers are made, copied the locks their kernels held)."""
    stream = _SlowBatches(4, seed=5, scene=SMALL, threads=2)
    it = iter(stream)
    next(it)
    it.close()
    assert sorted(stream.started) == sorted(stream.ended) and len(stream.ended) >= 2
    time.sleep(0.6)
    assert sorted(stream.started) == sorted(stream.ended)  # nothing not yet started ran after close either


def test_worker_loader_yields_the_streams_batches():
    """``stream.loader(n)``: the batches of ``iter(stream)``, bitwise and in order, rendered by worker processes
    and (after each worker's first batch, which learns the size) shipped through shared-memory slots; a rank's
    share as its iterator's; refused for a stream with gradients."""
    import itertools

    stream = PairStream(4, seed=3, scene=SMALL)
    loader = stream.loader(2)
    got = list(itertools.islice(iter(loader), 6))
    assert loader.shipped["slot"] >= 2
    for k, batch in enumerate(got):
        ref = stream.batch(k)
        for key in ref:
            if key != "meta":
                assert torch.equal(batch[key], ref[key]), (k, key)
        for m in META_KEYS:
            assert torch.equal(batch["meta"][m], ref["meta"][m]), (k, m)
    for _ in range(3):  # each new iterator starts again at batch 0 (a new epoch) ...
        again = list(itertools.islice(iter(loader), 4))
        assert all(torch.equal(a["raw"], b["raw"]) for a, b in zip(again, got))
    # ... and frees the slots of batches an abandoned iterator never took (else they stay busy and, after two
    # abandoned iterators, every batch takes the stock path)
    assert loader.shipped["slot"] >= 2
    share = PairStream(4, seed=3, scene=SMALL, rank=1, world_size=2, targets=("camera_rgb",))
    got = list(itertools.islice(iter(share.loader(1)), 2))
    assert [b["meta"]["index"].tolist() for b in got] == [[4, 5, 6, 7], [12, 13, 14, 15]]
    assert torch.equal(got[1]["raw"], share.batch(3)["raw"])
    # a resumed run's loader starts at its next batch, as batches(start) (the loader had no start: a resumed run
    # saw batches 0, 1, ... again)
    resumed = list(itertools.islice(iter(share.loader(1, start=5)), 2))
    assert [b["meta"]["index"].tolist() for b in resumed] == [[44, 45, 46, 47], [52, 53, 54, 55]]
    assert torch.equal(resumed[1]["raw"], next(share.batches(6))["raw"])
    with pytest.raises(ValueError, match="start: expected a non-negative index"):
        stream.loader(1, start=-1)
    with pytest.raises(ValueError, match="grad=True"):
        PairStream(4, scene=SMALL, grad=True).loader(2)
    with pytest.raises(ValueError, match="num_workers"):
        stream.loader(0)


def test_camera_module_receives_gradients():
    from isettorch import Camera
    from isettorch.optics import DiffractionLimitedOptics
    from isettorch.sensor import Sensor

    optics = DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3, learn_f_number=True)
    sensor = Sensor(rows=16, cols=16, pixel_size_m=2.0e-6, cfa="RGGB", learnable_filters=True,
                    exposure_s=torch.tensor(0.01, requires_grad=True), read_noise_v=1e-3)
    camera = Camera(optics, sensor)
    stream = PairStream(2, seed=0, scene={"height": 16, "width": 16}, camera=camera, targets=("camera_rgb",),
                        grad=True)
    batch = stream.batch(0)
    loss = batch["raw"].mean() + batch["camera_rgb"].mean()
    loss.backward()
    filt = [p for n, p in sensor.named_parameters() if p.requires_grad]
    assert filt, "the sensor's learnable filters"
    for p in (optics.f_number, sensor.exposure_s, *filt):
        assert p.grad is not None and torch.isfinite(p.grad).all() and float(p.grad.abs().sum()) > 0
    # f-number: a larger aperture (smaller N) gives more light, so the mean signal falls with N
    assert float(optics.f_number.grad) < 0
    # default: no graph
    no_grad = PairStream(2, seed=0, scene={"height": 16, "width": 16}, camera=camera, targets=("camera_rgb",))
    assert not no_grad.batch(0)["raw"].requires_grad


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="batch_size"):
        PairStream(0)
    with pytest.raises(ValueError, match="scene.generator"):
        PairStream(2, scene={"generator": "photos"})
    with pytest.raises(ValueError, match="dtype"):
        PairStream(2, dtype=torch.float16)
    with pytest.raises(ValueError, match="rank"):
        PairStream(2, rank=2, world_size=2)
    # world_size without rank (and no torch.distributed) became rank 0: every process trained the same share
    with pytest.raises(ValueError, match=r"rank: world_size 2 given without rank .*its rank in 0\.\.1"):
        PairStream(2, world_size=2)
    assert PairStream(2, world_size=1).rank == 0
    with pytest.raises(ValueError, match="k:"):
        PairStream(2, scene=SMALL).batch(-1)
    with pytest.raises(ValueError, match="scene.height"):
        PairStream(2, scene={"height": 31, "width": 32})


# --- the same distribution as the per-item generators ---------------------------------------------------------

def _scene_stats(maps, spectra, wl, h, w):
    """Per item: log mean luminance, mean chromaticity x, y and the mean |gradient| of log luminance."""
    v = _luminance_weights(wl.to(torch.float64))
    cmf = spectral.cmfs(wl.to(torch.float64), dtype=torch.float64).T  # [L, 3]
    lum = torch.einsum("bjl,l->bj", spectra.to(torch.float64), v)
    y_img = torch.einsum("bj,bjhw->bhw", lum, maps.to(torch.float64))
    xyz = torch.einsum("bjl,lc,bj->bc", spectra.to(torch.float64), cmf, maps.to(torch.float64).mean((-2, -1)))
    xy = xyz[:, :2] / xyz.sum(1, keepdim=True)
    logy = torch.log(y_img.clamp_min(1e-9))
    grad = (logy[:, 1:, :] - logy[:, :-1, :]).abs().mean((1, 2)) + (logy[:, :, 1:] - logy[:, :, :-1]).abs().mean((1, 2))
    return {"log_lum": torch.log(y_img.mean((1, 2))), "x": xy[:, 0], "y": xy[:, 1], "grad": grad}


def test_scene_distribution_matches_generate_scene():
    n, size = 192, 32
    cfg = merge_config(SMALL, SCENE_DEFAULTS, "scene")
    g = torch.Generator().manual_seed(11)
    parts = [draw_layout_scenes(64, g, cfg, size=(size, size), device="cpu", dtype=torch.float64)
             for _ in range(n // 64)]
    wl = parts[0]["wavelengths_nm"]
    stream_stats = {}
    for p in parts:
        for key, v in _scene_stats(p["maps"], p["spectra"], wl, size, size).items():
            stream_stats.setdefault(key, []).append(v)
    stream_stats = {k: torch.cat(v).numpy() for k, v in stream_stats.items()}
    item_stats: dict = {}
    layouts = []
    for i in range(n):
        s = generate_scene(i, 5, cfg, dtype=torch.float64)
        for key, v in _scene_stats(s.maps, s.spectra, wl, size, size).items():
            item_stats.setdefault(key, []).append(v)
        layouts.append(LAYOUT_CODES.index(s.metadata["layout"]))
    item_stats = {k: torch.cat(v).numpy() for k, v in item_stats.items()}
    for key in stream_stats:
        ok, info = _z_close(stream_stats[key], item_stats[key])
        assert ok, (key, info)
    # the layout mix: proportions within 4 standard errors of the configured weights
    weights = np.array([cfg["layouts"][name] for name in LAYOUT_CODES])
    p = weights / weights.sum()
    codes = torch.cat([q["meta"]["layout"] for q in parts]).numpy()
    for sample in (codes, np.asarray(layouts)):
        freq = np.bincount(sample, minlength=len(p)) / sample.size
        assert np.all(np.abs(freq - p) <= 4 * np.sqrt(p * (1 - p) / sample.size)), freq


def test_leaf_size_law():
    """Dead-leaf radii follow p(r) ~ r^-3 on [2.5, 0.6 size] (Lee, Mumford & Huang 2001): KS test against the
    closed-form CDF F(r) = (rmin^-2 - r^-2) / (rmin^-2 - rmax^-2)."""
    from scipy import stats

    cfg = merge_config({"layouts": {"dead_leaves": 1.0}}, SCENE_DEFAULTS, "scene")
    g = torch.Generator().manual_seed(2)
    out = draw_layout_scenes(8, g, cfg, size=(64, 64), device="cpu")
    r = out["meta"]["leaf_radius"]
    count = out["meta"]["leaf_count"]
    assert bool(((count >= 400) & (count <= 800)).all())
    radii = torch.cat([r[b, :int(count[b])] for b in range(8)]).numpy()
    rmin, rmax = 2.5, 0.6 * 64

    def cdf(x):
        return (rmin**-2 - np.clip(x, rmin, rmax) ** -2) / (rmin**-2 - rmax**-2)

    assert stats.kstest(radii, cdf).pvalue > 1e-3


def test_pair_distribution_matches_camera_pair_dataset():
    n = 64
    stream = PairStream(16, seed=9, scene=SMALL)
    sb = [stream.batch(k) for k in range(n // 16)]
    db = CameraPairDataset(n, seed=9, scene=SMALL).get_batch(list(range(n)))

    def stats_of(batch):
        cam = batch["camera_rgb"].to(torch.float64)
        lin = batch["linear_srgb"].to(torch.float64)
        lum = cam.mean(1)
        g = (lum[:, 1:] - lum[:, :-1]).abs().mean((1, 2)) / lum.mean((1, 2)).clamp_min(1e-6)
        return {"log_exposure": torch.log(batch["meta"]["exposure_s"].to(torch.float64)),
                "raw_mean": batch["raw"].to(torch.float64).mean((1, 2, 3)),
                "rg": cam[:, 0].mean((1, 2)) / cam[:, 1].mean((1, 2)),
                "bg": cam[:, 2].mean((1, 2)) / cam[:, 1].mean((1, 2)),
                "lin_r": lin[:, 0].mean((1, 2)), "rel_grad": g,
                "log_lum": torch.log(batch["meta"]["mean_luminance_cd_m2"].to(torch.float64)),
                "noise_gain": batch["meta"]["noise_gain"].to(torch.float64)}

    s = {k: torch.cat([stats_of(b)[k] for b in sb]).numpy() for k in stats_of(sb[0])}
    d = {k: v.numpy() for k, v in stats_of(db).items()}
    for key in s:
        ok, info = _z_close(s[key], d[key])
        assert ok, (key, info)


# --- distributed -------------------------------------------------------------------------------------------------

def _ddp_worker(rank: int, world: int, init_file: str, out_dir: str):
    torch.distributed.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=world)
    try:
        stream = PairStream(2, seed=5, scene={"height": 16, "width": 16}, targets=("camera_rgb",))
        it = iter(stream)
        got = [next(it) for _ in range(2)]
        torch.save({"rank": stream.rank, "world": stream.world_size,
                    "index": [b["meta"]["index"] for b in got], "raw": [b["raw"] for b in got]},
                   os.path.join(out_dir, f"rank{rank}.pt"))
        torch.distributed.barrier()
    finally:
        torch.distributed.destroy_process_group()


def test_distributed_ranks_draw_disjoint_batches(tmp_path):
    """Two gloo processes: rank r of W iterates over batches k W + r (no batch drawn twice, none skipped)."""
    torch.multiprocessing.spawn(_ddp_worker, args=(2, str(tmp_path / "init"), str(tmp_path)), nprocs=2)
    single = PairStream(2, seed=5, scene={"height": 16, "width": 16}, targets=("camera_rgb",), rank=0, world_size=1)
    seen = []
    for rank in range(2):
        rec = torch.load(tmp_path / f"rank{rank}.pt", weights_only=True)
        assert (rec["rank"], rec["world"]) == (rank, 2)
        for step, (index, raw) in enumerate(zip(rec["index"], rec["raw"])):
            k = step * 2 + rank
            assert index.tolist() == [2 * k, 2 * k + 1]
            assert torch.equal(raw, single.batch(k)["raw"])
            seen.append(k)
    assert sorted(seen) == [0, 1, 2, 3]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_stream_matches_cpu_rendering_of_the_same_scene():
    """CUDA renders a fixed drawn scene as the CPU does (1e-5 relative, TF32 off)."""
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    stream = PairStream(4, seed=0, scene=SMALL, camera={"pixel_size_m": [2.0e-6]}, targets=("camera_rgb",))
    (grp,) = stream.draw(0)
    cpu = grp.camera(grp.scene, return_intermediates=True, noise=False, **grp.kwargs).raw.noise_free
    cam = grp.camera.to("cuda")
    scene = grp.scene.to("cuda")
    kw = {k: v.to("cuda") for k, v in grp.kwargs.items()}
    gpu = cam(scene, return_intermediates=True, noise=False, **kw).raw.noise_free
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=1e-5, atol=1e-6)
    batch = PairStream(4, seed=0, scene=SMALL, device="cuda").batch(0)
    assert batch["raw"].device.type == "cuda" and batch["meta"]["exposure_s"].device.type == "cuda"


def test_batched_painter_equals_the_per_item_painter():
    """The batched dead-leaves painter (torch, all items at once) and the per-item one (numpy, kept for its speed
    on one item: about 2x) resolve occlusion identically: bitwise, item by item, in one batched call."""
    from isettorch.data import layouts
    from isettorch.data.batched import paint_leaves

    g = torch.Generator().manual_seed(0)
    h, w = 40, 56
    items, want = [], []
    for b in range(3):
        n = 60 + 20 * b
        r = layouts.dead_leaves_radii(n, 1.5, 0.6 * w, g)
        lo = torch.tensor([-0.1 * h, -0.1 * w, 0.0, 0.3], dtype=torch.float64)[:, None]
        hi = torch.tensor([1.1 * h, 1.1 * w, math.pi, 1.0], dtype=torch.float64)[:, None]
        cy, cx, theta, aspect = torch.rand(4, n, generator=g, dtype=torch.float64) * (hi - lo) + lo
        shape = torch.randint(0, 3, (n,), generator=g)
        items.append((torch.full((n,), b), cy, cx, r, theta, aspect, shape))
        want.append(layouts._paint_leaves(h, w, cy, cx, r, theta, aspect, shape, "cpu"))
    cat = [torch.cat(v) for v in zip(*items)]
    got = paint_leaves(h, w, cat[0], *cat[1:], 3)
    assert torch.equal(got, torch.stack(want))
    # the items' leaves interleaved (each item's in its drawing order): the same picture. The rank within an item
    # had assumed them grouped (item 0's second leaf painted as 2, item 1's first as none)
    slot_item = cat[0][torch.randperm(cat[0].numel(), generator=g)]  # the item of each position, shuffled
    pos = torch.empty_like(slot_item)
    for b in range(3):
        pos[slot_item == b] = torch.nonzero(cat[0] == b).reshape(-1)  # item b's leaves, in order, into its slots
    interleaved = paint_leaves(h, w, cat[0][pos], *[v[pos] for v in cat[1:]], 3)
    assert not torch.equal(cat[0][pos], cat[0]) and torch.equal(interleaved, got)


def test_layout_draw_puts_each_items_terms_first():
    """``draw_layout_scenes`` returns each item's terms (the palette colours it uses under each of its lights)
    first: maps and spectra beyond ``terms[b]`` are 0, ``used`` is that prefix, an item has n or 2 n terms (n <= K
    colours; two with a second light or a shadow), and every map it keeps is non-negative."""
    cfg = merge_config({"two_light_probability": 0.5, "shadow_probability": 0.5}, SCENE_DEFAULTS, "scene")
    out = draw_layout_scenes(12, torch.Generator().manual_seed(4), cfg, size=(40, 40), device="cpu")
    maps, spectra, terms = out["maps"], out["spectra"], out["terms"]
    k = cfg["palette_size"]
    assert maps.shape[1] == int(terms.max()) <= 2 * k
    j = torch.arange(maps.shape[1])
    assert torch.equal(out["used"], j[None] < terms[:, None])
    for b in range(12):
        t = int(terms[b])
        assert bool((maps[b, t:] == 0).all()) and bool((spectra[b, t:] == 0).all())
        assert bool((maps[b, :t] >= 0).all()) and bool((maps[b, :t].flatten(1).amax(1) > 0).any())
        lights = 2 if bool(out["meta"]["two_lights"][b] or out["meta"]["shadow"][b]) else 1
        assert t % lights == 0 and 1 <= t // lights <= k


def test_the_optics_buffer_keeps_a_bright_border_off_the_opposite_one():
    """A bright band on the scene's left border, f/8 at 1.4 um (a wide diffraction tail). With the FFT buffer the
    scene alone (version 7) the tail wrapped onto the right border: 48 % off there against the same scene rendered
    on a 128-sample buffer (the scene's edge continued); with the buffer twice the margin, edge-continued, 29 %."""
    from isettorch.scene import Scene

    s = PairStream(4, seed=2, scene={"height": 32, "width": 32},
                   camera={"f_number": [8.0], "pixel_size_m": [1.4e-6], "exposure_ev": [0.0, 0.0]}, targets=("xyz",))
    grp = s.draw(0)[0]
    assert (grp.camera.optics.margin, grp.camera.optics.pad_mode) == (16, "edge")
    sc = grp.scene
    nb, (h, w) = sc.maps.shape[0], sc.maps.shape[-2:]
    maps = torch.zeros(nb, 2, h, w)
    maps[:, 0], maps[:, 1, :, 0:4] = 1e-3, 1.0
    ill = sc.illuminant_photons
    band = Scene.from_factors(maps.to(sc.maps.dtype), torch.stack([ill, ill], 1).to(sc.spectra.dtype),
                              sc.wavelengths_nm, terms=[2] * nb, hfov_deg=sc.hfov_deg, distance_m=sc.distance_m,
                              illuminant_photons=ill, validate=False, metadata=sc.metadata, name="band")
    group = type(grp)(grp.index, grp.camera, band, grp.kwargs, grp.batch_index, grp.part)

    def right_border(margin, pad):
        grp.camera.optics.margin, grp.camera.optics.pad_mode = margin, pad
        out = s._render(group, torch.Generator().manual_seed(0))
        return out["xyz"][:, 1, :, -1].double() / out["meta"]["exposure_s"].double()[:, None]

    reference = right_border(128, "edge")
    shipped = float(((right_border(16, "edge") - reference).abs() / reference).max())
    periodic = float(((right_border(8, "zero") - reference).abs() / reference).max())
    assert shipped < 0.35 and periodic > 0.45


def test_batches_do_not_keep_their_groups_optics():
    """Each group's drawn optics (a new module per group, with its assembled OTF) is released after its batch: the
    stream's camera cache kept a Camera per group, so memory grew with every batch (on the device path 3.1 MiB per
    128^2 pair per batch; 88 MiB per pair after a throughput run's 27 batches, 92 MB measured on an H200)."""
    import gc

    from isettorch.optics.diffraction import DiffractionLimitedOptics

    def live_optics():
        gc.collect()
        return sum(isinstance(o, DiffractionLimitedOptics) for o in gc.get_objects())

    stream = PairStream(4, seed=3, scene=SMALL, camera={"cfa_patterns": ["RGGB", "GRBG"]})
    stream.batch(0)
    before = live_optics()
    first = stream.batch(1)
    for k in range(2, 7):
        stream.batch(k)
    assert live_optics() == before
    # and the batches are unchanged by it: batch 1 again, after the others, is bitwise the same
    again = stream.batch(1)
    for key in ("raw", *stream.targets):
        assert torch.equal(first[key], again[key])


def test_a_stream_and_a_dataset_of_one_seed_draw_from_different_generators():
    """PairStream's batch k, part 0, was seeded as CameraPairDataset's item k (the streams 0 and 2 of seed_for): a
    validation dataset of the training seed shared scenes and noise with the training stream (r 0.1-0.2)."""
    from isettorch.data.config import seed_for

    stream = PairStream(4, seed=7, scene=SMALL)
    dataset = {seed_for(7, i, s) for i in range(64) for s in range(4)}
    for k in range(8):
        for kind in (0, 2):
            for part in range(2):
                assert stream._generator(k, kind, part).initial_seed() not in dataset, (k, kind, part)


def test_a_learnable_analog_gain_at_one_gets_its_gradient():
    """A volts readout's white level was clamp(gain x swing, max=swing): at gain 1, the Sensor's default, the clamp
    passed the gradient, the white followed the gain and the targets (divided by it) had zero gradient in the gain.
    Autograd now equals the right-hand finite difference (above 1 the white is the swing), as at gain 2."""
    from isettorch import Camera
    from isettorch.optics import DiffractionLimitedOptics
    from isettorch.sensor import Sensor

    dt = torch.float64

    def mean_rgb(g0, grad):
        gain = torch.nn.Parameter(torch.tensor(g0, dtype=dt)) if grad else torch.tensor(g0, dtype=dt)
        sensor = Sensor(rows=16, cols=16, pixel_size_m=2e-6, cfa="RGGB", exposure_s=0.01, adc_bits=None,
                        analog_gain=gain).to(dt)
        cam = Camera(DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3).to(dt), sensor)
        s = PairStream(2, seed=1, scene={"height": 16, "width": 16}, camera=cam, grad=True, dtype=dt,
                       targets=("noise_free_raw", "camera_rgb"))
        m = s.batch(0)["camera_rgb"].mean()
        return (m, torch.autograd.grad(m, sensor.analog_gain)[0]) if grad else m

    for g0 in (1.0, 2.0):
        m, g = mean_rgb(g0, True)
        fd = float((mean_rgb(g0 + 1e-6, False) - m.detach()) / 1e-6)
        assert fd > 0.1
        assert float(g) == pytest.approx(fd, rel=0.02)  # (saturated pixels take the left derivative at gain 1)
