"""A cache of tensors bounded in entries and in bytes: OTFs are kept per scene geometry, and a folder of photographs
of many sizes added a full OTF per size (about 630 MB each at 2048^2: +4.2 GB over 20 sizes, found by a memory
audit of 2026-12-01)."""

from __future__ import annotations

import threading
from collections import OrderedDict

import torch

#: bytes a cache keeps beyond its newest entry (which is always kept: the call that made it uses it)
DEFAULT_MAX_BYTES = 512 * 2**20


def nbytes(value) -> int:
    """Bytes of the tensors in ``value`` (a tensor, or a tuple / list / dict of them)."""
    if isinstance(value, torch.Tensor):
        return value.numel() * value.element_size()
    if isinstance(value, (tuple, list)):
        return sum(nbytes(v) for v in value)
    if isinstance(value, dict):
        return sum(nbytes(v) for v in value.values())
    return 0


def _normal(value):
    """``value`` with its inference tensors cloned outside inference mode: an entry first made under
    ``torch.inference_mode`` would be refused by autograd in every later call ('Inference tensors cannot be saved
    for backward')."""
    if isinstance(value, torch.Tensor):
        if value.is_inference():
            with torch.inference_mode(False):
                return value.clone()
        return value
    if isinstance(value, tuple):
        return tuple(_normal(v) for v in value)
    if isinstance(value, list):
        return [_normal(v) for v in value]
    return value


class BoundedCache(OrderedDict):
    """An ``OrderedDict`` that drops its oldest entries past ``max_entries`` or ``max_bytes`` (the newest always
    stays); a hit read through :meth:`get` becomes the newest. Reads and writes hold a lock (a stream renders its
    parts on threads that share one cache of OTF rows)."""

    def __init__(self, max_entries: int, max_bytes: int = DEFAULT_MAX_BYTES):
        super().__init__()
        self.max_entries, self.max_bytes = int(max_entries), int(max_bytes)
        self._lock = threading.RLock()

    def get(self, key, default=None):
        with self._lock:
            if key in self:
                self.move_to_end(key)
                return self[key]
            return default

    def __setitem__(self, key, value) -> None:
        value = _normal(value)
        with self._lock:
            super().__setitem__(key, value)
            self.move_to_end(key)
            while len(self) > 1 and (len(self) > self.max_entries
                                     or sum(map(nbytes, self.values())) > self.max_bytes):
                self.popitem(last=False)

    def __reduce__(self):  # (pickled as its class and limits, empty: a cache is not state)
        return type(self), (self.max_entries, self.max_bytes)
