"""Per-item OTF rows (DiffractionLimitedOptics): a batch of items with their own f-numbers and spacings gets the
same OTF from cached rows as from one batched evaluation, and a new combination of known items evaluates nothing."""

import torch

from isettorch.optics import DiffractionLimitedOptics
from isettorch.scene import Scene


def _scene(hfov):
    g = torch.Generator().manual_seed(0)
    maps = torch.rand(len(hfov), 2, 24, 24, generator=g, dtype=torch.float64)
    spectra = torch.rand(len(hfov), 2, 31, generator=g, dtype=torch.float64) * 1e15
    return Scene.from_factors(maps, spectra, torch.arange(400.0, 701.0, 10.0, dtype=torch.float64),
                              hfov_deg=torch.tensor(hfov, dtype=torch.float64), distance_m=1.2)


def test_rows_equal_the_batched_otf_and_are_reused():
    scene = _scene([3.0, 5.0, 3.0])
    n = torch.tensor([2.0, 4.0, 2.0], dtype=torch.float64)
    rows = DiffractionLimitedOptics(f_number=n, focal_length_m=4e-3)
    whole = DiffractionLimitedOptics(f_number=n, focal_length_m=4e-3)
    whole.otf_rows_independent = False  # the batched evaluation
    a, b = rows(scene).photons, whole(scene).photons
    assert torch.equal(a, b)
    assert len(rows._otf_rows) == 2  # items 0 and 2 share (f-number, spacing)
    calls = []
    original = rows.otf
    rows.otf = lambda *args: calls.append(1) or original(*args)
    rows.f_number = torch.nn.Parameter(torch.tensor([2.0, 2.0, 4.0], dtype=torch.float64), requires_grad=False)
    swapped = _scene([3.0, 3.0, 5.0])
    out = rows(swapped).photons
    assert not calls  # assembled from the cached rows
    ref = DiffractionLimitedOptics(f_number=torch.tensor([2.0, 2.0, 4.0], dtype=torch.float64), focal_length_m=4e-3)
    ref.otf_rows_independent = False
    assert torch.equal(out, ref(swapped).photons)
