"""A CPU :class:`~isettorch.data.stream.PairStream` rendered in worker processes.

On a CPU, one Python process renders a stream batch with torch's many small operations, and two threads of one
process share the GIL (``benchmarks/THROUGHPUT.md``): on 2 cores the stream in the main process runs at about 0.6x
the rate of two DataLoader worker processes at batch 16. When no gradient to the camera is wanted, the same batches
can come from worker processes instead: :func:`stream_loader` hands batch indices to a ``DataLoader``'s workers,
each renders ``stream.batch(k)`` (a pure function of the stream's config and ``k``) and ships it through the
shared-memory slots of :mod:`isettorch.data.shm_slots`, and the main process receives them in order. The batches
are bitwise those of ``iter(stream)`` (the workers run torch on one intra-op thread, as the DataLoader sets them;
a batch does not depend on the thread count).
"""

from __future__ import annotations

import itertools

import torch

from .config import seed_for, tune_allocator
from .shm_slots import SlotArena, SlotLoader, SlotRequest

__all__ = ["stream_loader"]


class _StreamBatches(torch.utils.data.Dataset):
    """Map-style view of a stream: item ``k`` is ``stream.batch(k)``; in a worker, a :class:`SlotRequest` is
    answered through the worker's shared-memory slots."""

    def __init__(self, stream):
        self.stream = stream

    def __getitem__(self, request):
        k = int(request[0]) if isinstance(request, list) else int(request)
        batch = self.stream.batch(k)
        if not (isinstance(request, SlotRequest) and torch.utils.data.get_worker_info() is not None):
            return batch
        arena = self.__dict__.get("_arena")
        if arena is None:
            arena = self._arena = SlotArena(request.slots)
        bump = arena.acquire(request.epoch)
        if bump.storage is None:  # no slot free (or the size not learnt yet): the stock path
            return arena.finish(batch, bump)

        def copy(t: torch.Tensor) -> torch.Tensor:
            return bump(t.numel(), t.dtype).view(t.shape).copy_(t)

        placed = {key: ({m: copy(t) for m, t in v.items()} if isinstance(v, dict) else copy(v))
                  for key, v in batch.items()}
        return arena.finish(placed, bump)


class _BatchIndices(torch.utils.data.Sampler):
    """The batch indices a stream's iterator takes, ``first + i * world_size`` for i = 0, 1, ..., without end, as
    :class:`SlotRequest` s (``slots`` per worker). Each new iterator is a new epoch, so slots still holding batches
    that an abandoned iterator never took are freed (:meth:`SlotArena.acquire`)."""

    def __init__(self, first: int, world_size: int, slots: int):
        self.first, self.world_size, self.slots, self.epoch = first, world_size, slots, 0

    def __iter__(self):
        self.epoch += 1
        epoch = self.epoch
        for i in itertools.count():
            request = SlotRequest([self.first + i * self.world_size])
            request.slots, request.epoch = self.slots, epoch
            yield request


def _init_worker(_: int) -> None:
    tune_allocator()  # large temporaries stay in the worker's heap (isettorch.data.config.tune_allocator)


def stream_loader(stream, num_workers: int = 2, *, prefetch_factor: int = 2, start: int = 0) -> SlotLoader:
    """An endless iterable of ``stream``'s batches, in the order of ``stream.batches(start)`` and bitwise the same
    (``start`` 0: ``iter(stream)``; a resumed training run's next batch), rendered by ``num_workers`` worker
    processes (see the module docstring). For a CPU stream without gradients: a stream that builds the autograd
    graph (``grad=True``) or lives on another device renders in its own process (``iter(stream)``).

    Example:
        >>> from isettorch.data import PairStream
        >>> stream = PairStream(4, seed=0, scene={"height": 32, "width": 32}, targets=("camera_rgb",))
        >>> batch = next(iter(stream_loader(stream, num_workers=1)))
        >>> bool(torch.equal(batch["raw"], stream.batch(0)["raw"]))
        True
    """
    if not isinstance(num_workers, int) or isinstance(num_workers, bool) or num_workers < 1:
        raise ValueError(f"num_workers: expected a positive integer, got {num_workers!r}")
    if not isinstance(prefetch_factor, int) or isinstance(prefetch_factor, bool) or prefetch_factor < 1:
        raise ValueError(f"prefetch_factor: expected a positive integer, got {prefetch_factor!r}")
    if stream.device.type != "cpu":
        raise ValueError(f"stream: worker processes render CPU streams; this one is on {stream.device} (iterate it "
                         f"directly)")
    if stream.grad:
        raise ValueError("stream: a stream with grad=True builds an autograd graph, which worker processes cannot "
                         "hand back; iterate it directly")
    first = stream._first_batch(start)  # checked before any worker starts
    sampler = _BatchIndices(first, stream.world_size, prefetch_factor + 1)
    # the workers' base seed from a generator of the stream's own (the batches do not use it): the loader drew it
    # from the global generator on every iter(), moving a training run's own draws
    base = torch.Generator().manual_seed(seed_for(stream.seed, -1))  # (index -1: no batch's generator)
    return SlotLoader(_StreamBatches(stream), sampler=sampler, batch_size=None, num_workers=num_workers,
                      prefetch_factor=prefetch_factor, persistent_workers=True, worker_init_fn=_init_worker,
                      generator=base)
