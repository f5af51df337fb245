"""Dead leaves: determinism, occlusion order, coverage statistics, radius distribution."""

import numpy as np
import pytest
import scipy.stats
import torch

from isettorch.scene import dead_leaves, macbeth_reflectances
from isettorch.scene.dead_leaves import expected_disk_area_px2

F64 = torch.float64


def test_seed_determinism():
    a = dead_leaves(24, seed=7, dtype=F64)
    b = dead_leaves(24, seed=7, dtype=F64)
    c = dead_leaves(24, generator=torch.Generator().manual_seed(7), dtype=F64)
    d = dead_leaves(24, seed=8, dtype=F64)
    assert torch.equal(a.photons, b.photons) and torch.equal(a.photons, c.photons)
    assert not torch.equal(a.photons, d.photons)
    batch = dead_leaves(24, seed=7, batch_size=2, dtype=F64)
    assert torch.equal(batch.metadata["labels"][0], a.metadata["labels"][0])  # sample 0 is the single draw
    assert torch.allclose(batch.photons[:1], a.photons, rtol=1e-12)
    assert not torch.equal(batch.photons[0], batch.photons[1])


def test_front_to_back_occlusion():
    """Each pixel shows the first drawn disk that covers its centre (recomputed by brute force)."""
    s = dead_leaves((20, 28), rmin_px=1.5, rmax_px=6.0, seed=3, dtype=F64)
    labels = s.metadata["labels"][0]
    centres, radii = s.metadata["centres_px"][0], s.metadata["radii_px"][0]
    assert (labels >= 0).all() and s.metadata["uncovered_fraction"] == [0.0]
    yy, xx = torch.meshgrid(torch.arange(20, dtype=F64), torch.arange(28, dtype=F64), indexing="ij")
    inside = (yy[None] - centres[:, 0, None, None]) ** 2 + (xx[None] - centres[:, 1, None, None]) ** 2 \
        <= radii[:, None, None] ** 2
    first = torch.where(inside.any(0), inside.to(torch.uint8).argmax(0), -1)
    assert torch.equal(first, labels)
    # the last disk kept is the one that covered the last pixel
    assert labels.max().item() == radii.numel() - 1
    # one flat grey level per visible disk
    refl = s.reflectance()[0]
    assert torch.allclose(refl, refl[:1].expand_as(refl), rtol=1e-9)
    for lab in torch.unique(labels)[:20].tolist():
        v = refl[0][labels == lab]
        assert torch.allclose(v, v[:1].expand_as(v), rtol=1e-9)
        assert 0.05 - 1e-9 <= v[0].item() <= 0.95 + 1e-9


def _expected_disk_area(alpha, rmin, rmax):
    r = np.linspace(rmin, rmax, 200001)
    pdf = r ** -alpha
    return np.trapezoid(np.pi * r**2 * pdf, r) / np.trapezoid(pdf, r)


@pytest.mark.parametrize("alpha", [1.0, 2.0, 3.0, 4.5])
def test_expected_disk_area_closed_form(alpha):
    assert expected_disk_area_px2(alpha, 1.5, 30.0) == pytest.approx(_expected_disk_area(alpha, 1.5, 30.0), rel=1e-6)


def test_coverage_fraction_boolean_model():
    """With n disks, a pixel is uncovered with probability (1 - E[pi r^2] / A)^n, A the area the centres are
    drawn from (the image extended by rmax on each side)."""
    rows, cols, rmin, rmax, alpha, n = 32, 32, 1.0, 8.0, 3.0, 200
    s = dead_leaves((rows, cols), alpha=alpha, rmin_px=rmin, rmax_px=rmax, num_disks=n, batch_size=8, seed=11,
                    dtype=F64)
    area = (rows - 1 + 2 * rmax) * (cols - 1 + 2 * rmax)
    expected = (1 - _expected_disk_area(alpha, rmin, rmax) / area) ** n
    measured = float(np.mean(s.metadata["uncovered_fraction"]))
    assert 0.2 < expected < 0.6
    assert measured == pytest.approx(expected, abs=0.04)
    # uncovered pixels are black (reflectance 0)
    for i in range(8):
        assert (s.photons[i][:, s.metadata["labels"][i] < 0] == 0).all()
    assert all(len(r) == n for r in s.metadata["radii_px"])


def test_radius_distribution_power_law():
    alpha, rmin, rmax = 3.0, 1.0, 20.0
    s = dead_leaves(16, alpha=alpha, rmin_px=rmin, rmax_px=rmax, num_disks=3000, seed=5, dtype=F64)
    r = s.metadata["radii_px"][0].numpy()
    assert r.min() >= rmin and r.max() <= rmax

    def cdf(a):
        return lambda x: (x ** (1 - a) - rmin ** (1 - a)) / (rmax ** (1 - a) - rmin ** (1 - a))

    assert scipy.stats.kstest(r, cdf(alpha)).pvalue > 0.01
    assert scipy.stats.kstest(r, cdf(2.5)).pvalue < 1e-6  # the test tells exponents apart


def test_macbeth_and_custom_reflectances():
    s = dead_leaves(16, reflectances="macbeth", seed=2, dtype=F64)
    refl = s.reflectance()[0].reshape(31, -1).T  # [pixels, L]
    mac = macbeth_reflectances(s.wavelengths_nm)
    dist = torch.cdist(refl, mac, compute_mode="donot_use_mm_for_euclid_dist").amin(dim=1)
    assert dist.max() < 1e-9
    table = torch.tensor([[0.2] * 31, [0.6] * 31], dtype=F64)
    s2 = dead_leaves(16, reflectances=table, seed=2, dtype=F64)
    vals = torch.unique(s2.reflectance()[0].round(decimals=9))
    assert vals.tolist() == [0.2, 0.6]


@pytest.mark.parametrize("kwargs,exc,match", [
    ({"size": -8}, ValueError, "size"),
    ({"alpha": 0.0}, ValueError, "alpha"),
    ({"rmin_px": 5.0, "rmax_px": 2.0}, ValueError, "rmax_px"),
    ({"seed": None}, ValueError, "seed"),
    ({"generator": 3}, TypeError, "generator"),
    ({"reflectances": "rainbow"}, ValueError, "reflectances"),
    ({"reflectances": torch.ones(4, 7)}, ValueError, "reflectances"),
    ({"num_disks": 0}, ValueError, "num_disks"),
    ({"reflectance_range": (0.8, 0.2)}, ValueError, "reflectance_range"),
])
def test_errors(kwargs, exc, match):
    kwargs = {"size": 8, **kwargs}
    with pytest.raises(exc, match=match):
        dead_leaves(**kwargs)


def test_large_images_are_covered_and_bad_draws_are_named():
    """texture audit (2026-12-01): at the fixed 200,000 disks a 512-pixel image kept about 312 black pixels (the
    Boolean model above; 347 drawn); the default now draws what the image needs. Too few disks, a default rmax
    below rmin, an all-black range and radii too small to ever cover the image are named; equal radii have an
    expected area (it divided by zero)."""
    rows = cols = 512
    rmin, rmax, alpha = 1.0, 256.0, 3.0
    area = (rows - 1 + 2 * rmax) * (cols - 1 + 2 * rmax)
    uncovered = lambda n: rows * cols * (1 - _expected_disk_area(alpha, rmin, rmax) / area) ** n  # noqa: E731
    from isettorch.scene.dead_leaves import max_disks_for

    assert uncovered(200_000) > 100 and uncovered(max_disks_for(rows, cols, alpha, rmin, rmax)) < 1e-6
    with pytest.raises(ValueError, match=r"max_disks: 3 disks left \d+ of 256 pixels uncovered"):
        dead_leaves(16, max_disks=3)
    with pytest.raises(ValueError, match=r"size: a 1 x 8 image's default rmax_px, min\(H, W\) / 2 = 0.5, is below"):
        dead_leaves((1, 8))
    with pytest.raises(ValueError, match=r"reflectance_range: \(0, 0\) makes every leaf black"):
        dead_leaves(16, reflectance_range=(0, 0))
    with pytest.raises(ValueError, match=r"rmin_px, alpha: disks of 0.01 to 32 px with exponent 200 are too small .*"
                                         r"about 4.29e\+08 needed.*pass max_disks"):
        dead_leaves(64, alpha=200.0, rmin_px=0.01)  # (an OverflowError)
    assert expected_disk_area_px2(3.0, 2.0, 2.0) == pytest.approx(np.pi * 4.0)
    # rmax -> infinity: pi rmin^2 (alpha - 1) / (alpha - 3); (8 / 0.01)^-197 is nothing (rmin^-199 overflowed)
    assert expected_disk_area_px2(200.0, 0.01, 8.0) == pytest.approx(np.pi * 1e-4 * 199 / 197, rel=1e-12)


def test_num_disks_draws_exactly_that_many_whatever_the_coverage_need():
    """With num_disks the need-based refusal does not apply (it refused tiny radii drawn a fixed number of times)."""
    s = dead_leaves(64, alpha=200.0, rmin_px=0.01, num_disks=50, seed=0, mean_luminance_cd_m2=None)
    assert s.metadata["radii_px"][0].numel() == 50 and s.metadata["uncovered_fraction"][0] > 0.99


def test_radii_stay_finite_and_in_range_at_extreme_exponents():
    """rmin ** (1 - alpha) underflows to 0 at alpha 100, rmin 3000 px, and the radii came out inf (the overflow
    side was handled). They are the truncated power law's: in [rmin, rmax] with its mean, (1 - alpha) / (2 - alpha)
    x (rmax^(2 - alpha) - rmin^(2 - alpha)) / (rmax^(1 - alpha) - rmin^(1 - alpha)), here 1.0102 rmin. Near alpha 1,
    rounding had reached 3e-5 beyond rmax."""
    from isettorch.scene.dead_leaves import sample_power_law_radii

    g = torch.Generator().manual_seed(0)
    alpha, rmin, rmax = 100.0, 3000.0, 6000.0
    r = sample_power_law_radii(20000, alpha, rmin, rmax, g)
    assert bool(torch.isfinite(r).all()) and float(r.min()) >= rmin and float(r.max()) <= rmax
    x = rmax / rmin  # the mean over rmin, in closed form relative to rmin (no under/overflow)
    mean = (1 - alpha) / (2 - alpha) * (x ** (2 - alpha) - 1) / (x ** (1 - alpha) - 1)
    assert float(r.mean()) / rmin == pytest.approx(mean, abs=5e-4) and mean == pytest.approx(1.0102, abs=1e-4)
    near_one = sample_power_law_radii(100000, 1 + 1.5e-12, 1.0, 1e6, g)
    assert float(near_one.max()) <= 1e6 and float(near_one.min()) >= 1.0
