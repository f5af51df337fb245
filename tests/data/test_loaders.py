"""DataLoader workers and DistributedSampler: every item exactly once, bitwise identical everywhere."""

import platform
import sys

import pytest
import torch
from torch.utils.data import DataLoader
from torch.utils.data.distributed import DistributedSampler

from isettorch.data import SyntheticSceneDataset, collate_scenes
from isettorch.data.camera_pairs import CameraPairDataset, collate_pairs

TINY = {"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 50.0]}


def _pairs(ds, **kw):
    loader = DataLoader(ds, batch_size=2, collate_fn=collate_pairs, **kw)
    return [b for b in loader]


def test_camera_pairs_identical_across_0_1_2_workers():
    ds = CameraPairDataset(6, seed=9, scene=TINY)
    runs = [_pairs(ds, num_workers=n) for n in (0, 1, 2)]
    ref = runs[0]
    assert torch.cat([b["meta"]["index"] for b in ref]).tolist() == list(range(6))
    for other in runs[1:]:
        for a, b in zip(ref, other, strict=True):
            for k in ("raw", "noise_free_raw", "camera_rgb", "xyz", "linear_srgb", "srgb"):
                assert torch.equal(a[k], b[k]), k
            for k in a["meta"]:
                assert torch.equal(a["meta"][k], b["meta"][k]), k


def test_scenes_identical_across_workers():
    ds = SyntheticSceneDataset(4, seed=3, config=TINY)
    a = [s.photons for s in DataLoader(ds, batch_size=2, collate_fn=collate_scenes, num_workers=0)]
    b = [s.photons for s in DataLoader(ds, batch_size=2, collate_fn=collate_scenes, num_workers=2)]
    assert len(a) == 2 and all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def test_distributed_sampler_covers_every_item_once():
    """Three simulated ranks (in-process), shuffled, one of them with 2 workers: the union of the items they
    load is the dataset, with no duplicate, and each item equals the one built directly."""
    n, world = 12, 3
    ds = CameraPairDataset(n, seed=4, scene=TINY)
    direct = {i: ds[i] for i in range(n)}
    seen = []
    for rank in range(world):
        sampler = DistributedSampler(ds, num_replicas=world, rank=rank, shuffle=True, seed=17)
        sampler.set_epoch(1)
        loader = DataLoader(ds, batch_size=2, sampler=sampler, collate_fn=collate_pairs,
                            num_workers=2 if rank == 1 else 0)
        for batch in loader:
            for j, idx in enumerate(batch["meta"]["index"].tolist()):
                seen.append(idx)
                assert torch.equal(batch["raw"][j], direct[idx]["raw"])
                assert torch.equal(batch["camera_rgb"][j], direct[idx]["camera_rgb"])
    assert sorted(seen) == list(range(n))


def test_items_do_not_depend_on_the_thread_count():
    """Main process (several threads) and DataLoader workers (one thread) must build identical items."""
    # large enough (> 32768 elements per plane) for torch to split reductions and GEMMs across threads
    ds = CameraPairDataset(2, seed=1, scene={"height": 192, "width": 192, "wavelengths_nm": [400.0, 700.0, 50.0]})
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        a = ds[1]
        torch.set_num_threads(1)
        b = ds[1]
    finally:
        torch.set_num_threads(before)
    for k in ("raw", "noise_free_raw", "camera_rgb", "xyz", "linear_srgb", "srgb"):
        assert torch.equal(a[k], b[k]), k


class _TunedFlag(CameraPairDataset):
    """Reports, with each item, whether this process has applied tune_allocator."""

    def __getitem__(self, index):
        item = super().__getitem__(index)
        from isettorch.data import camera_pairs

        return {"raw": item["raw"], "tuned": torch.tensor(camera_pairs._WORKER_TUNED is True)}


@pytest.mark.skipif(not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc", reason="glibc mallopt")
def test_allocator_tuned_in_workers_only_and_values_unchanged():
    """Workers apply tune_allocator before their first item (the main process never does), and the items are
    bitwise those of the main process."""
    from isettorch.data import camera_pairs

    ds = _TunedFlag(4, seed=3, scene={"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 50.0]})
    main = [ds[i] for i in range(4)]
    assert camera_pairs._WORKER_TUNED is None  # the main process never tunes
    got = list(DataLoader(ds, batch_size=None, num_workers=2))
    assert all(bool(g["tuned"]) for g in got)
    for a, b in zip(main, got):
        assert torch.equal(a["raw"], b["raw"])
    off = _TunedFlag(2, seed=3, scene={"height": 16, "width": 16}, tune_worker_allocator=False)
    assert not any(bool(g["tuned"]) for g in DataLoader(off, batch_size=None, num_workers=1))
