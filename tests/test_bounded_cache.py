"""OTF caches bounded in bytes as well as entries (a memory audit of 2026-12-01: a folder of photographs of many
sizes added a full OTF per size, about 630 MB each at 2048^2, +4.2 GB over 20 sizes)."""

import torch

from isettorch._cache import BoundedCache, nbytes
from isettorch.optics import DiffractionLimitedOptics
from isettorch.scene import uniform


def test_bounded_cache_drops_the_oldest_past_its_bytes_and_keeps_the_newest():
    c = BoundedCache(max_entries=10, max_bytes=3 * 800)
    for k in range(4):
        c[k] = torch.zeros(100, dtype=torch.float64)  # 800 bytes each
    assert list(c) == [1, 2, 3]
    assert c.get(1) is not None and list(c) == [2, 3, 1]  # a hit becomes the newest
    c[9] = torch.zeros(1000, dtype=torch.float64)  # larger than the budget alone: kept, the rest dropped
    assert list(c) == [9]
    assert nbytes((torch.zeros(2), {"a": torch.zeros(3, dtype=torch.float64)})) == 8 + 24


def test_optics_otf_cache_stays_within_its_bytes_over_many_scene_sizes():
    optics = DiffractionLimitedOptics(f_number=4.0)
    optics._otf_cache.max_bytes = 2**20
    for n in range(24, 120, 8):
        optics(uniform(size=n))
        held = sum(nbytes(v) for v in optics._otf_cache.values())
        newest = nbytes(next(reversed(optics._otf_cache.values())))
        assert held <= max(2**20, newest)
    assert len(optics._otf_cache) < 8  # the bytes bound it (a count-only bound kept 8 OTFs of any size)
