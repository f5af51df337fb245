"""A factored scene whose items use different numbers of terms: on a CPU the optics weight, pad and transform only
each item's used maps (``ShiftInvariantLens._used_term_spectra``). The optical image must be bitwise the one of the
whole-batch path (every map weighted and padded, then each item's used maps transformed), whatever the pad mode,
relative illumination, crop window or precision."""

import pytest
import torch

from isettorch.optics import DiffractionLimitedOptics
from isettorch.optics.optical_image import FourierFactors
from isettorch.scene import Scene

WAVE = torch.arange(400.0, 701.0, 10.0)


def _scene(terms, dtype, j=5, size=24, seed=1):
    """Items with their own FOV whose maps from ``terms[b]`` on are 0, with the term counts given."""
    g = torch.Generator().manual_seed(seed)
    maps = torch.rand(len(terms), j, size, size, generator=g, dtype=torch.float64).to(dtype)
    for b, t in enumerate(terms):
        maps[b, t:] = 0
    spectra = (torch.rand(len(terms), j, len(WAVE), generator=g, dtype=torch.float64) * 1e15).to(dtype)
    hfov = torch.linspace(3.0, 5.0, len(terms), dtype=dtype)
    return Scene.from_factors(maps, spectra, WAVE.to(dtype), terms=terms, hfov_deg=hfov, distance_m=1.2)


def _optics(n, dtype, **kw):
    return DiffractionLimitedOptics(f_number=torch.tensor(n, dtype=dtype), focal_length_m=4e-3, margin=8, **kw)


def _spy(optics) -> list:
    """Count the calls of the used-terms path on ``optics``."""
    calls, method = [], optics._used_term_spectra
    optics._used_term_spectra = lambda *a, **k: calls.append(1) or method(*a, **k)
    return calls


def _whole_batch(optics):
    """``optics`` forced through the whole-batch path (every item's J maps weighted and padded)."""
    optics._by_used_terms = lambda *a, **k: False
    return optics


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("pad_mode", ["zero", "edge"])
@pytest.mark.parametrize("ri", ["cos4th", None])
@pytest.mark.parametrize("crop", [None, (3, 5, 17, 20)])
@pytest.mark.parametrize("terms", [(5, 2, 3, 0), (0, 4, 1, 5), (1, 1)])
def test_used_terms_are_bitwise_the_whole_batch_path(dtype, pad_mode, ri, crop, terms):
    scene = _scene(terms, dtype)
    n = [2.0, 4.0, 8.0, 2.8, 5.6][:len(terms)]
    fast = _optics(n, dtype, pad_mode=pad_mode, relative_illumination=ri)
    calls = _spy(fast)
    ref = _whole_batch(_optics(n, dtype, pad_mode=pad_mode, relative_illumination=ri))
    a, b = fast(scene, crop=crop), ref(scene, crop=crop)
    assert calls == [1]  # the used-terms path ran (and not on the reference)
    fa, fb = a.factors, b.factors
    assert isinstance(fa, FourierFactors) and isinstance(fb, FourierFactors)  # blurred: the rFFT path
    assert fa.terms == fb.terms == terms
    assert fa.spec.shape == fb.spec.shape and fa.spec.dtype == fb.spec.dtype
    assert torch.equal(fa.spec, fb.spec)
    for i, t in enumerate(terms):  # each item's used spectra transformed, the rest exactly 0
        assert bool((fa.spec[i, :t].abs().amax(dim=(-2, -1)) > 0).all())
        assert not bool(fa.spec[i, t:].any())
    assert torch.equal(fa.spectra, fb.spectra)
    assert (fa.size, fa.window) == (fb.size, fb.window)
    assert len(fa.otf_rows) == len(fb.otf_rows) and all(torch.equal(x, y) for x, y in zip(fa.otf_rows, fb.otf_rows))
    assert a.metadata == b.metadata and (a.pad_rows, a.pad_cols) == (b.pad_rows, b.pad_cols)
    assert torch.equal(a.sample_spacing_m, b.sample_spacing_m) and torch.equal(a.hfov_deg, b.hfov_deg)
    w = torch.rand(len(WAVE), 3, generator=torch.Generator().manual_seed(2), dtype=dtype)
    assert torch.equal(a.project(w), b.project(w))
    assert torch.equal(a.photons, b.photons)


@pytest.mark.parametrize("pad_mode", ["zero", "edge"])
def test_maps_beyond_the_term_counts_are_not_read(pad_mode):
    """The used-terms path reads item ``i``'s maps ``j < terms[i]`` only: later maps made NaN change nothing."""
    terms = (4, 1, 0, 2)
    clean, poisoned = _scene(terms, torch.float32), _scene(terms, torch.float32)
    for b, t in enumerate(terms):
        poisoned.maps[b, t:] = float("nan")
    n = [2.0, 4.0, 8.0, 2.8]
    a = _optics(n, torch.float32, pad_mode=pad_mode)(poisoned).factors.spec
    b = _whole_batch(_optics(n, torch.float32, pad_mode=pad_mode))(clean).factors.spec
    assert torch.equal(a, b)


def test_used_terms_match_each_item_alone():
    """Item ``i``'s spectrum of its used maps is the one of the item rendered alone with only those maps (its own
    FOV, f-number and relative illumination): a wrong item, term count or weighting would not match."""
    terms = (3, 1, 4)
    scene = _scene(terms, torch.float64, j=4, seed=3)
    n = [2.0, 4.0, 8.0]
    oi = _optics(n, torch.float64, pad_mode="edge")(scene)
    for i, t in enumerate(terms):
        one = Scene.from_factors(scene.maps[i:i + 1, :t], scene.spectra[i:i + 1, :t], scene.wavelengths_nm,
                                 hfov_deg=scene.hfov_deg[i:i + 1], distance_m=1.2)
        alone = _optics(n[i:i + 1], torch.float64, pad_mode="edge")(one)
        torch.testing.assert_close(oi.factors.spec[i, :t], alone.factors.spec[0], rtol=1e-12, atol=0)


@pytest.mark.parametrize("case", ["mean", "grad", "one_item", "no_terms", "no_hint"])
def test_other_cases_keep_the_whole_batch_path(case):
    """A reducing pad mode, a gradient, one item, items without terms or no term counts: not the used-terms path."""
    terms = {"one_item": (3,), "no_terms": (0, 0)}.get(case, (3, 1))
    scene = _scene(terms, torch.float64, j=3)
    if case == "no_hint":
        scene = Scene.from_factors(scene.maps, scene.spectra, scene.wavelengths_nm, hfov_deg=scene.hfov_deg,
                                   distance_m=1.2)
    if case == "grad":
        scene = Scene.from_factors(scene.maps.clone().requires_grad_(), scene.spectra, scene.wavelengths_nm,
                                   terms=terms, hfov_deg=scene.hfov_deg, distance_m=1.2)
    optics = _optics([2.0, 4.0][:len(terms)], torch.float64, pad_mode="mean" if case == "mean" else "edge")
    calls = _spy(optics)
    oi = optics(scene)
    assert not calls
    if case == "grad":
        oi.photons.sum().backward()
        assert scene.maps.grad is not None
