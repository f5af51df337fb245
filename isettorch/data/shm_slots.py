"""Ship generated batches from DataLoader workers through reusable shared-memory slots.

A stock ``DataLoader`` worker moves every batch into **fresh** shared memory when it pickles it: a new shm segment
per tensor storage, whose pages the kernel allocates and zeroes on first touch, then a copy, then one file descriptor
per storage passed to the main process and mapped there. For camera pairs (0.92 MB per 128 x 128 pair with every
target) that cost 0.9 ms of worker CPU per pair (0.6 ms of it kernel time: 270 page faults per pair) against
5.5 ms to render it (``benchmarks/THROUGHPUT.md``).

Here each worker renders a batch directly into one of a few shared-memory **slots** it keeps for its lifetime (the
pages are faulted in once), and ships a small :class:`SlotBatch` handle (the slot's storage, whose mapping the main
process keeps, and every tensor's dtype, offset and shape). The main process copies the batch out of the slot into
ordinary memory and marks the slot free again (a flag in the slot's header, read by the worker before reuse), so a
batch the user holds is never overwritten. A worker with no free slot (the main process is slow to consume, or a
batch needs more bytes than the slot has) falls back to the stock path for that batch: values are identical either
way (a byte copy). Batches the DataLoader itself discards (an epoch abandoned midway with ``persistent_workers``)
never reach the main process's copy: their slots are freed by the worker when the next epoch's first batch reaches
it (each request carries its epoch; the DataLoader drains every batch of an epoch before it sends the next one's).

Used by :func:`isettorch.data.camera_pairs.batch_loader`; the handle never reaches user code.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["SlotArena", "SlotBatch", "SlotRequest", "SlotBatchSampler", "EpochLoader", "SlotLoader", "unpack"]

_ALIGN = 64  # bytes: every tensor starts on a cache line (and on a multiple of any element size)
_HEADER = 64  # bytes before the first tensor; int32 flag at 0: 1 while the main process has not copied the batch


def _align(n: int) -> int:
    return -(-n // _ALIGN) * _ALIGN


def _flag(storage: torch.UntypedStorage) -> torch.Tensor:
    return torch.empty(0, dtype=torch.int32).set_(storage, 0, (1,))


class SlotRequest(list):
    """The indices of one batch, marked for shipping through a slot (what :class:`SlotLoader`'s sampler yields),
    with the number of slots a worker keeps and the epoch (the sampler's iteration) the batch belongs to."""

    slots: int = 3
    epoch: int = 0


class _Bump:
    """Allocator of 1-D tensors, one after the other, in a slot; ordinary tensors once the slot is full (or without
    one, ``storage=None``). ``used`` counts the bytes the batch needs either way."""

    def __init__(self, storage: torch.UntypedStorage | None):
        self.storage, self.used, self.overflow = storage, _HEADER, storage is None

    def __call__(self, numel: int, dtype: torch.dtype) -> torch.Tensor:
        size = torch.empty(0, dtype=dtype).element_size()
        start = _align(self.used)
        self.used = start + numel * size
        if self.storage is not None and self.used > self.storage.nbytes():
            self.overflow = True
        if self.overflow:
            return torch.empty(numel, dtype=dtype)
        return torch.empty(0, dtype=dtype).set_(self.storage, start // size, (numel,))


class SlotArena:
    """Worker side: up to ``count`` slots, each one shared-memory storage sized by the largest batch seen."""

    def __init__(self, count: int):
        if count < 1:
            raise ValueError(f"count: expected at least one slot, got {count}")
        self.count, self.slots, self.nbytes = count, [], 0
        self.epoch, self.slot_epochs = 0, {}  # the latest epoch seen; each slot's epoch (by storage pointer)

    def acquire(self, epoch: int = 0) -> _Bump:
        """An allocator over a free slot (marked busy); without a slot (every slot still held by the main process,
        the batch size not yet learnt, or no shared memory to be had) one that hands out ordinary tensors.
        Call :meth:`finish` with the rendered batch. ``epoch``: the batch's epoch; the first batch of a later epoch
        frees the slots still busy with batches of earlier ones (discarded by the DataLoader, never copied out)."""
        if epoch > self.epoch:
            for storage in self.slots:
                if self.slot_epochs.get(storage.data_ptr(), epoch) < epoch:
                    _flag(storage).fill_(0)
            self.epoch = epoch
        for storage in self.slots:
            if storage.nbytes() >= self.nbytes and int(_flag(storage)) == 0:
                _flag(storage).fill_(1)
                self.slot_epochs[storage.data_ptr()] = epoch
                return _Bump(storage)
        self.slots = [s for s in self.slots if s.nbytes() >= self.nbytes]  # outgrown slots are dropped
        if len(self.slots) >= self.count or self.nbytes == 0:
            return _Bump(None)  # the first batch learns the size on the stock path
        try:
            storage = torch.UntypedStorage._new_shared(self.nbytes)
        except (RuntimeError, OSError):  # e.g. /dev/shm full: the stock path still works
            return _Bump(None)
        _flag(storage).fill_(1)
        self.slots.append(storage)
        self.slot_epochs[storage.data_ptr()] = epoch
        return _Bump(storage)

    def finish(self, batch: dict, bump: _Bump):
        """What the worker returns for ``batch`` rendered with ``bump``: its :class:`SlotBatch` handle, or (no slot,
        or the slot overflowed) the batch itself, holding no memory of a slot (copied out, the slot freed)."""
        self.nbytes = max(self.nbytes, bump.used)
        handle = SlotBatch.pack(batch, bump)
        if handle is not None:
            return handle
        if bump.storage is not None:
            self.abandon(bump, batch)
        return batch

    def abandon(self, bump: _Bump, batch: dict | None = None) -> None:
        """Free ``bump``'s slot; tensors of ``batch`` in it are replaced by copies first (so nothing the stock path
        ships maps a slot that the next batch overwrites)."""
        if batch is not None:
            base = bump.storage.data_ptr()
            for key, value in batch.items():
                inner = value if isinstance(value, dict) else {None: value}
                for k, t in inner.items():
                    if isinstance(t, torch.Tensor) and t.untyped_storage().data_ptr() == base:
                        inner[k] = t.clone()
                if not isinstance(value, dict):
                    batch[key] = inner[None]
        _flag(bump.storage).fill_(0)


class SlotBatch:
    """A batch (a dict of tensors and dicts of tensors) that lies in a worker's slot: its storage, the bytes used
    and, per tensor, ``(dtype, byte offset, shape)``."""

    __slots__ = ("storage", "nbytes", "tree")

    def __init__(self, storage, nbytes, tree):
        self.storage, self.nbytes, self.tree = storage, nbytes, tree

    def __reduce__(self):
        return SlotBatch, (self.storage, self.nbytes, self.tree)

    @classmethod
    def pack(cls, batch: dict, bump: _Bump) -> SlotBatch | None:
        """The handle of ``batch`` if every tensor in it is a contiguous view of ``bump``'s slot, else None."""
        if bump.overflow or bump.storage is None:
            return None
        base = bump.storage.data_ptr()

        def spec(t):
            if not (isinstance(t, torch.Tensor) and t.is_contiguous() and t.untyped_storage().data_ptr() == base):
                raise _NotInSlot
            return (t.dtype, t.storage_offset() * t.element_size(), tuple(t.shape))

        try:
            tree = {k: ({m: spec(t) for m, t in v.items()} if isinstance(v, dict) else spec(v))
                    for k, v in batch.items()}
        except _NotInSlot:
            return None
        return cls(bump.storage, bump.used, tree)


class _NotInSlot(Exception):
    pass


def unpack(handle: SlotBatch) -> dict:
    """Main process: the batch copied out of its slot into ordinary memory (one storage), then the slot freed."""
    n = handle.nbytes - _HEADER
    flat = torch.empty(n, dtype=torch.uint8)
    # one memcpy on this thread (numpy): torch would split it over its intra-op threads, whose spinning after the
    # copy takes cores from the workers (measured 320 -> 350 pairs/s with 2 threads in the main process)
    np.copyto(flat.numpy(), torch.empty(0, dtype=torch.uint8).set_(handle.storage, _HEADER, (n,)).numpy())
    _flag(handle.storage).fill_(0)  # after the copy: the worker may now write the next batch there
    storage = flat.untyped_storage()

    def view(spec):
        dtype, offset, shape = spec
        t = torch.empty(0, dtype=dtype)
        return t.set_(storage, (offset - _HEADER) // t.element_size(), shape)

    return {k: ({m: view(s) for m, s in v.items()} if isinstance(v, dict) else view(v)) for k, v in handle.tree.items()}


class SlotBatchSampler(torch.utils.data.BatchSampler):
    """A ``BatchSampler`` whose batches are :class:`SlotRequest` lists asking for ``slots`` slots per worker."""

    def __init__(self, sampler, batch_size: int, drop_last: bool, slots: int):
        super().__init__(sampler, batch_size, drop_last)
        self.slots, self.epoch = slots, 0

    def __iter__(self):
        self.epoch += 1
        epoch = self.epoch
        for indices in super().__iter__():
            request = SlotRequest(indices)
            request.slots, request.epoch = self.slots, epoch
            yield request


class EpochLoader(torch.utils.data.DataLoader):
    """A ``DataLoader`` whose persistent workers' later epochs take from ``generator`` the draw a fresh iterator
    takes for its workers' base seed (torch draws it only when it starts the workers; the draw is discarded, the
    workers keep their first seeds): a sampler on the same generator then shuffles every epoch as it does with
    ``num_workers=0`` or without persistent workers (from the second epoch, the orders differed)."""

    def __iter__(self):
        if self.persistent_workers and self.num_workers > 0 and self._iterator is not None:
            torch.empty((), dtype=torch.int64).random_(generator=self.generator)  # _BaseDataLoaderIter's base seed
        return super().__iter__()


class SlotLoader(EpochLoader):
    """A ``DataLoader`` whose batches may arrive as :class:`SlotBatch` handles: it yields them copied out (plain
    dicts of tensors). The main process keeps each slot's mapping for the iterator's life (no remapping per
    batch). ``shipped``: how the last iteration's batches came, ``{"slot": n, "stock": m}``."""

    shipped: dict | None = None

    def __iter__(self):
        it = super().__iter__()
        held = {}
        self.shipped = shipped = {"slot": 0, "stock": 0}
        for batch in it:
            if isinstance(batch, SlotBatch):
                held.setdefault(batch.storage.data_ptr(), batch.storage)
                batch = unpack(batch)
                shipped["slot"] += 1
            else:
                shipped["stock"] += 1
            yield batch
