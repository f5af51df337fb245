"""Per-item OTF rows (DiffractionLimitedOptics): a batch of items with their own f-numbers and spacings gets the
same OTF from cached rows as from one batched evaluation, and a new combination of known items evaluates nothing."""

import pytest
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


def _termed_scene(terms, hfov=(3.0, 5.0, 4.0), j=5):
    """Items whose maps from ``terms[b]`` on are 0, with the hint given or not."""
    g = torch.Generator().manual_seed(1)
    maps = torch.rand(len(terms), j, 24, 24, generator=g, dtype=torch.float64)
    for b, t in enumerate(terms):
        maps[b, t:] = 0
    spectra = torch.rand(len(terms), j, 31, generator=g, dtype=torch.float64) * 1e15
    wave = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    kw = dict(hfov_deg=torch.tensor(hfov, dtype=torch.float64), distance_m=1.2)
    return (Scene.from_factors(maps, spectra, wave, terms=terms, **kw), Scene.from_factors(maps, spectra, wave, **kw),
            [Scene.from_factors(maps[b:b + 1, :t], spectra[b:b + 1, :t], wave, hfov_deg=hfov[b], distance_m=1.2)
             for b, t in enumerate(terms)])


def test_term_counts_transform_only_the_used_maps():
    """An optics given each item's term count (its later maps 0) transforms only the used maps: the same optical
    image, projected and dense, as without the hint (bitwise: the skipped terms add exact zeros) and as each item on
    its own with only its terms (float rounding)."""
    hinted, plain, alone = _termed_scene([5, 2, 3])
    zero, zero_plain, _ = _termed_scene([5, 0, 3])  # an item without terms (a black scene) is no special case
    optics0 = DiffractionLimitedOptics(f_number=torch.tensor([2.0, 4.0, 8.0], dtype=torch.float64),
                                       focal_length_m=4e-3, margin=8)
    assert torch.equal(optics0(zero).photons, optics0(zero_plain).photons)
    n = torch.tensor([2.0, 4.0, 8.0], dtype=torch.float64)
    optics = DiffractionLimitedOptics(f_number=n, focal_length_m=4e-3, margin=8)
    oi_h, oi_p = optics(hinted), optics(plain)
    assert oi_h.factors.terms == (5, 2, 3) and oi_p.factors.terms is None
    assert isinstance(oi_h.factors.otf_rows, tuple) and len(oi_h.factors.otf_rows) == 3  # no stacked batch OTF
    w = torch.rand(31, 4, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    assert torch.equal(oi_h.project(w), oi_p.project(w))
    assert torch.equal(oi_h.photons, oi_p.photons)
    for b, scene in enumerate(alone):
        one = DiffractionLimitedOptics(f_number=float(n[b]), focal_length_m=4e-3, margin=8)(scene)
        torch.testing.assert_close(oi_h.project(w)[b:b + 1], one.project(w), rtol=1e-12, atol=0)
    # a selection keeps its items' terms and rows
    sub = oi_h.factors.select(torch.tensor([2, 0]))
    assert sub.terms == (3, 5) and len(sub.otf_rows) == 2
    torch.testing.assert_close(sub.project(w), oi_h.project(w)[[2, 0]], rtol=1e-12, atol=0)


def test_term_counts_are_checked():
    hinted, _, _ = _termed_scene([5, 2, 3])
    maps, spectra = hinted.factors.maps, hinted.factors.spectra
    wave = hinted.wavelengths_nm
    with pytest.raises(ValueError, match="terms: a map beyond"):
        Scene.from_factors(maps, spectra, wave, terms=[5, 1, 3])  # item 1's second map is not 0
    with pytest.raises(ValueError, match="terms: expected 3 counts"):
        Scene.from_factors(maps, spectra, wave, terms=[5, 2])
    with pytest.raises(ValueError, match="terms: expected 3 counts"):
        Scene.from_factors(maps, spectra, wave, terms=[5, 2, 6])


def test_accelerator_path_equals_the_per_item_path(monkeypatch):
    """The batched path the optics take on an accelerator (one stacked OTF, every item's maps padded to the most
    terms) gives the per-item CPU path's optical image (float rounding): run here on the CPU by switching
    ``per_item_products`` off."""
    from isettorch.optics import base

    hinted, _, _ = _termed_scene([5, 2, 3])
    n = torch.tensor([2.0, 4.0, 8.0], dtype=torch.float64)
    w = torch.rand(31, 4, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    per_item = DiffractionLimitedOptics(f_number=n, focal_length_m=4e-3, margin=8)(hinted)
    assert per_item.factors.otf_rows is not None and per_item.factors.terms == (5, 2, 3)
    monkeypatch.setattr(base, "per_item_products", lambda device: False)
    batched = DiffractionLimitedOptics(f_number=n, focal_length_m=4e-3, margin=8)(hinted)
    assert batched.factors.otf_rows is None and batched.factors.terms is None
    torch.testing.assert_close(batched.project(w), per_item.project(w), rtol=1e-12, atol=0)
    torch.testing.assert_close(batched.photons, per_item.photons, rtol=1e-12, atol=0)


def test_a_module_reused_across_buffer_widths_of_either_parity_is_a_fresh_one():
    """The OTF cache keyed the rFFT's Mx // 2 + 1 columns, which widths 2k and 2k + 1 share on other frequencies:
    a module that had blurred a 20-wide scene (buffer 24) blurred a 21-wide one (buffer 25) with the 24-wide OTF,
    4 % of the peak off. The same module equals a fresh one on both."""
    import math

    from isettorch import Scene
    from isettorch.optics import DiffractionLimitedOptics

    w_nm = torch.tensor([550.0], dtype=torch.float64)
    d_i, dx = 1 / (1 / 4e-3 - 1 / 1.2), 1.1e-6

    def scene(w):
        x = torch.zeros(1, 1, 16, w, dtype=torch.float64)
        x[0, 0, 8, w // 2] = 1.0
        return Scene(x, w_nm, hfov_deg=2 * math.degrees(math.atan(w * dx / (2 * d_i))), distance_m=1.2)

    def optics():
        return DiffractionLimitedOptics(4.0, 4e-3, margin=2, relative_illumination=None)

    o = optics()
    for w in (20, 21, 20):
        got = o(scene(w)).photons
        want = optics()(scene(w)).photons
        assert torch.equal(got, want), w
