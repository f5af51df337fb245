"""Shared-memory slot transport of DataLoader batches (isettorch.data.shm_slots): a batch copied out of its slot
equals the rendered batch bitwise, a batch the user holds is never overwritten by a later one in the same slot,
and every fallback (no slot yet, all slots busy, overflow) returns the batch without memory of a slot."""

import pytest
import torch

from isettorch.data.camera_pairs import CameraPairDataset, batch_loader
from isettorch.data.shm_slots import SlotArena, SlotBatch, SlotLoader, unpack

TINY = {"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 50.0]}
KEYS = ("raw", "noise_free_raw", "camera_rgb", "xyz", "linear_srgb", "srgb")


def _batch(alloc, value: float) -> dict:
    """A batch shaped like the pairs': two images in one storage, float and long metadata in others."""
    flat = alloc(2 * 3 * 4 * 4 + 2 * 4 * 4, torch.float32)
    img = flat[:96].view(2, 3, 4, 4).fill_(value)
    raw = flat[96:].view(2, 1, 4, 4).copy_(torch.arange(32.0).view(2, 1, 4, 4) + value)
    meta_f = alloc(2, torch.float64).copy_(torch.tensor([value, -value], dtype=torch.float64))
    meta_l = alloc(3, torch.long).copy_(torch.tensor([1, 2, 3]) * int(value))
    return {"raw": raw, "srgb": img, "meta": {"gain": meta_f, "cfa": meta_l}}


def _expected(value: float) -> dict:
    return _batch(lambda n, dtype: torch.empty(n, dtype=dtype), value)


def _assert_equal(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k, v in a.items():
        if isinstance(v, dict):
            _assert_equal(v, b[k])
        else:
            assert v.dtype == b[k].dtype and v.shape == b[k].shape and torch.equal(v, b[k]), k


def test_slot_round_trip_and_reuse_keeps_held_batches():
    arena = SlotArena(2)
    first = arena.acquire()
    assert first.storage is None  # the first batch learns the size on the ordinary path
    out = arena.finish(_batch(first, 1.0), first)
    assert isinstance(out, dict)
    _assert_equal(out, _expected(1.0))
    held = []
    for value in range(2, 8):  # more batches than slots: each copied out before its slot is reused
        bump = arena.acquire()
        assert bump.storage is not None
        handle = arena.finish(_batch(bump, float(value)), bump)
        assert isinstance(handle, SlotBatch)
        held.append((value, unpack(handle)))
    assert len(arena.slots) == 1  # each slot was freed by unpack before the next acquire
    for value, batch in held:
        _assert_equal(batch, _expected(float(value)))


def test_busy_slots_fall_back_and_overflow_leaves_no_slot_memory():
    arena = SlotArena(1)
    b0 = arena.acquire()
    arena.finish(_batch(b0, 1.0), b0)
    b1 = arena.acquire()
    h1 = arena.finish(_batch(b1, 2.0), b1)
    assert isinstance(h1, SlotBatch)
    b2 = arena.acquire()  # the only slot is still held (not unpacked): ordinary tensors
    assert b2.storage is None
    out = arena.finish(_batch(b2, 3.0), b2)
    assert isinstance(out, dict)
    _assert_equal(out, _expected(3.0))
    _assert_equal(unpack(h1), _expected(2.0))
    # a bigger batch than the slot: the part that fit is copied out and the slot freed
    b3 = arena.acquire()
    slot = b3.storage
    big = {"a": b3(8, torch.float32).fill_(5.0), "b": b3(10**5, torch.float32).fill_(6.0)}
    out = arena.finish(big, b3)
    assert isinstance(out, dict) and b3.overflow
    assert all(t.untyped_storage().data_ptr() != slot.data_ptr() for t in out.values())
    assert torch.equal(out["a"], torch.full((8,), 5.0)) and torch.equal(out["b"], torch.full((10**5,), 6.0))
    b4 = arena.acquire()  # the outgrown slot is replaced by one of the new size
    assert b4.storage is not None and b4.storage.nbytes() >= 4 * (10**5 + 8)


def test_pack_refuses_tensors_outside_the_slot():
    arena = SlotArena(1)
    b0 = arena.acquire()
    arena.finish(_batch(b0, 1.0), b0)
    b1 = arena.acquire()
    batch = _batch(b1, 2.0)
    batch["meta"]["extra"] = torch.ones(2)  # not in the slot: the handle would lose it
    out = arena.finish(batch, b1)
    assert isinstance(out, dict)
    assert torch.equal(out["meta"]["extra"], torch.ones(2))
    assert all(t.untyped_storage().data_ptr() != b1.storage.data_ptr()
               for t in (out["raw"], out["srgb"], out["meta"]["gain"]))
    assert arena.acquire().storage is b1.storage  # freed


def test_worker_batches_through_slots_equal_main_process_batches():
    """2 workers, 10 batches of 2 (more than the 3 slots per worker), all held until the end: every batch equals
    the one rendered in the main process, bitwise, metadata included."""
    ds = CameraPairDataset(20, seed=3, scene=TINY)
    loader = batch_loader(ds, 2, num_workers=2)
    assert isinstance(loader, SlotLoader)
    got = list(loader)
    assert loader.shipped["slot"] >= 10 - 2 * 1  # each worker's first batch learns the slot size
    assert loader.shipped["slot"] + loader.shipped["stock"] == 10
    for b, batch in enumerate(got):
        ref = ds.get_batch([2 * b, 2 * b + 1])
        for k in KEYS:
            assert torch.equal(batch[k], ref[k]), (b, k)
        for k, v in ref["meta"].items():
            assert batch["meta"][k].dtype == v.dtype and torch.equal(batch["meta"][k], v), (b, k)


def test_persistent_workers_reuse_their_slots_across_epochs():
    ds = CameraPairDataset(12, seed=3, scene=TINY)
    loader = batch_loader(ds, 2, num_workers=2, persistent_workers=True)
    ref = [ds.get_batch([2 * b, 2 * b + 1])["raw"] for b in range(6)]
    first, second = list(loader), list(loader)
    assert loader.shipped == {"slot": 6, "stock": 0}  # the slots freed in epoch 1 serve all of epoch 2
    for got in (first, second):
        assert all(torch.equal(b["raw"], r) for b, r in zip(got, ref, strict=True))


def test_pinned_or_custom_collate_loaders_use_the_stock_path():
    ds = CameraPairDataset(4, seed=3, scene=TINY)
    assert not isinstance(batch_loader(ds, 2, num_workers=1, collate_fn=lambda b: b), SlotLoader)
    assert not isinstance(batch_loader(ds, 2, num_workers=0), SlotLoader)
    assert not isinstance(batch_loader(ds, 2, num_workers=1, shm_slots=False), SlotLoader)
    with pytest.raises(ValueError, match="count"):
        SlotArena(0)


def test_batch_loader_keeps_its_workers_across_epochs():
    """Workers persist by default (num_workers > 0): two epochs give the same batches as the main process, from the
    same worker processes, the second wholly through the slots the first freed; the user's choice is kept."""
    ds = CameraPairDataset(12, seed=3, scene=TINY)
    loader = batch_loader(ds, 2, num_workers=2)
    assert loader.persistent_workers
    ref = [ds.get_batch([2 * b, 2 * b + 1]) for b in range(6)]
    first = list(loader)
    pids = [w.pid for w in loader._iterator._workers]
    second = list(loader)
    assert [w.pid for w in loader._iterator._workers] == pids and all(w.is_alive() for w in loader._iterator._workers)
    assert loader.shipped == {"slot": 6, "stock": 0}
    for got in (first, second):
        for b, r in zip(got, ref, strict=True):
            assert all(torch.equal(b[k], r[k]) for k in KEYS)
            assert all(torch.equal(b["meta"][k], v) for k, v in r["meta"].items())
    assert not batch_loader(ds, 2, num_workers=2, persistent_workers=False).persistent_workers
    assert not batch_loader(ds, 2).persistent_workers  # no workers to keep


def test_an_abandoned_epoch_frees_its_slots_at_the_next_epoch():
    """Batches the DataLoader discards (an epoch left midway) are never copied out; the worker frees their slots
    when the next epoch's first request reaches it, so later epochs still ship every batch through a slot."""
    arena = SlotArena(2)
    b0 = arena.acquire(1)
    arena.finish(_batch(b0, 1.0), b0)  # learns the size
    busy = [arena.acquire(1) for _ in range(2)]
    for bump in busy:
        assert isinstance(arena.finish(_batch(bump, 2.0), bump), SlotBatch)  # shipped, never unpacked
    assert arena.acquire(1).storage is None  # the same epoch: both slots are (rightly) busy
    fresh = arena.acquire(2)  # the next epoch: the discarded batches' slots are free again
    assert fresh.storage is not None and fresh.storage.data_ptr() in {b.storage.data_ptr() for b in busy}
    ds = CameraPairDataset(12, seed=3, scene=TINY)
    loader = batch_loader(ds, 2, num_workers=2)
    for _ in range(3):  # three epochs left midway (their prefetched batches discarded by the DataLoader) would
        for _ in loader:  # keep all three slots of each worker busy: every batch then took the stock path
            break
    list(loader)
    assert loader.shipped == {"slot": 6, "stock": 0}
