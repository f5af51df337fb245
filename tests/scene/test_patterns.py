"""Uniform fields and spatial test patterns: each one's defining property, measured on the output."""

import math

import colour
import numpy as np
import pytest
import scipy.constants as sc
import torch

from isettorch import scene as sg

F64 = torch.float64
W10 = torch.arange(400.0, 701.0, 10.0, dtype=F64)


def _refl(s):
    """The pattern (relative reflectance) [H, W] of a neutral pattern scene, from its photons."""
    r = s.reflectance()[0]
    assert torch.allclose(r, r[:1].expand_as(r), rtol=1e-9, atol=1e-12)  # spectrally neutral
    return r[0]


def _crossings(profile: torch.Tensor, level: float) -> torch.Tensor:
    """Sub-pixel positions where a 1-D profile crosses ``level`` (linear interpolation)."""
    d = (profile - level).double()
    up = (d[:-1] < 0) & (d[1:] >= 0)
    down = (d[:-1] > 0) & (d[1:] <= 0)
    idx = torch.nonzero(up | down).flatten()
    return idx + d[idx] / (d[idx] - d[idx + 1])


# ---------------------------------------------------------------------------------------------
# Mean luminance, dtype and size of every generator

GENERATORS = {
    "macbeth": lambda **k: sg.macbeth(patch_size=2, **k),
    "uniform": lambda **k: sg.uniform("D65", 4, **k),
    "monochromatic": lambda **k: sg.monochromatic(550.0, 4, **k),
    "ramp": lambda **k: sg.ramp(8, **k),
    "ramp_exp": lambda **k: sg.ramp(8, "exponential", **k),
    "frequency_sweep": lambda **k: sg.frequency_sweep(16, **k),
    "slanted_edge": lambda **k: sg.slanted_edge(16, 7.0, **k),
    "point_array": lambda **k: sg.point_array(16, 8, **k),
    "grid_lines": lambda **k: sg.grid_lines(16, 8, **k),
    "star": lambda **k: sg.star(16, 8, **k),
    "checkerboard": lambda **k: sg.checkerboard(16, 4, **k),
    "zone_plate": lambda **k: sg.zone_plate(16, **k),
    "hdr_chart": lambda **k: sg.hdr_chart(6, 1, 2, **k),
    "dead_leaves": lambda **k: sg.dead_leaves(16, seed=0, **k),
    "reflectance_scene": lambda **k: sg.reflectance_scene(torch.rand(31, 3, 3, generator=torch.Generator()
                                                                     .manual_seed(0)), **k),
}


@pytest.mark.parametrize("name", sorted(GENERATORS))
@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_mean_luminance_100(name, dtype):
    s = GENERATORS[name](dtype=dtype)
    assert s.dtype == dtype and s.batch_size == 1
    assert abs(s.mean_luminance().item() - 100.0) <= 1e-5 * 100.0
    s2 = GENERATORS[name](dtype=dtype, mean_luminance_cd_m2=3.5, hfov_deg=4.0, distance_m=2.0)
    assert abs(s2.mean_luminance().item() - 3.5) <= 1e-5 * 3.5
    assert s2.hfov_deg.item() == pytest.approx(4.0) and s2.distance_m.item() == pytest.approx(2.0)


@pytest.mark.parametrize("name", sorted(set(GENERATORS) - {"monochromatic", "reflectance_scene"}))
def test_wavelength_grid_argument(name):
    w = torch.tensor([450.0, 550.0, 650.0], dtype=F64)
    s = GENERATORS[name](wavelengths=w)
    assert s.num_wavelengths == 3 and torch.equal(s.wavelengths_nm, w)
    assert s.mean_luminance().item() == pytest.approx(100.0, rel=1e-9)


# ---------------------------------------------------------------------------------------------
# Uniform fields


@pytest.mark.parametrize("name,reference", [
    ("D65", lambda w: colour.SDS_ILLUMINANTS["D65"][w]),
    ("equal_energy", lambda w: np.ones_like(w)),
    ("equal_photon", lambda w: 1.0 / w),
    ("blackbody5000", lambda w: colour.sd_blackbody(5000, colour.SpectralShape(400, 700, 10))[w]),
])
def test_uniform_spectral_shape(name, reference):
    s = sg.uniform(name, (3, 5), dtype=F64)
    lum = s.luminance()
    assert torch.allclose(lum, torch.full_like(lum, 100.0), rtol=1e-12)
    energy = s.energy()[0, :, 1, 2]
    ref = torch.tensor(np.asarray(reference(W10.numpy()), float))
    ratio = energy / ref
    assert torch.allclose(ratio, ratio.mean().expand_as(ratio), rtol=1e-9)
    assert torch.allclose(s.reflectance(), torch.ones_like(s.photons), rtol=1e-12)


def test_uniform_tensor_spectrum():
    spd = torch.linspace(1.0, 2.0, 31, dtype=F64)
    s = sg.uniform(spd, 2, dtype=F64)
    e = s.energy()[0, :, 0, 0]
    assert torch.allclose(e / spd, (e / spd)[:1].expand(31), rtol=1e-12)


def test_monochromatic_absolute_radiance():
    """100 cd/m^2 at 550 nm in a 1 nm band: E = 100 / (683 V(550)) W/sr/m^2/nm, N = E lambda / (h c)."""
    s = sg.monochromatic(550.0, 3, dtype=F64)
    v550 = colour.colorimetry.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"][550]
    expected = 100.0 / (683.0 * v550) * 550e-9 / (sc.h * sc.c)
    assert torch.allclose(s.photons, torch.full_like(s.photons, expected), rtol=1e-10)
    s2 = sg.monochromatic(600.0, 2, wavelengths=W10)
    p = s2.photons[0, :, 0, 0]
    assert (p[W10 != 600] == 0).all() and p[20] > 0
    assert s2.mean_luminance().item() == pytest.approx(100.0, rel=1e-5)



@pytest.mark.parametrize("lam", [632.8, 589.3, 550.1])
def test_monochromatic_at_a_wavelength_float32_rounds(lam):
    # A laser's 632.8 nm is 632.79999 in float32: the 1e-6 nm match refused it at the default dtype ('expected one
    # of the grid's samples [632.7999877929688]'); float64 worked. Both give 100 cd/m^2 at that wavelength.
    for dtype in (torch.float32, F64):
        s = sg.monochromatic(lam, 2, dtype=dtype)
        assert s.wavelengths_nm.tolist() == pytest.approx([lam], abs=1e-4)
        assert s.mean_luminance().item() == pytest.approx(100.0, rel=1e-5)
    grid = torch.tensor([500.0, lam, 700.0])
    p = sg.monochromatic(lam, 2, wavelengths=grid).photons[0, :, 0, 0]
    assert p[0] == 0 and p[2] == 0 and p[1] > 0


# ---------------------------------------------------------------------------------------------
# Ramps, sweep, edge


def test_linear_ramp():
    s = sg.ramp((3, 17), dark_level=0.1, dtype=F64)
    lum = s.luminance()[0, 0]
    assert torch.allclose(lum, lum[:1].expand_as(lum), rtol=1e-12)  # constant down the columns
    row = lum[0]
    assert (row[1:] > row[:-1]).all()
    assert torch.allclose(row[2:] - 2 * row[1:-1] + row[:-2], torch.zeros(15, dtype=F64), atol=1e-9 * row.max())
    assert (row[0] / row[-1]).item() == pytest.approx(0.1, rel=1e-12)


def test_exponential_ramp():
    s = sg.ramp((2, 11), "exponential", dynamic_range=1e4, dtype=F64)
    row = s.luminance()[0, 0, 0]
    ratios = row[1:] / row[:-1]
    assert torch.allclose(ratios, torch.full_like(ratios, 10 ** 0.4), rtol=1e-10)
    assert (row[-1] / row[0]).item() == pytest.approx(1e4, rel=1e-10)


def test_frequency_sweep_local_frequency():
    """Zero crossings of the top row are where pi f u^2 = pi/2 + k pi, u = col / W: the local frequency is
    f u cycles per image width (a linear sweep; ISETCam's imgSweep rises as 3 f u^2)."""
    cols, f = 128, 32.0
    r = _refl(sg.frequency_sweep((8, cols), f, dtype=F64))
    x = _crossings(r[0], 0.5)
    k = torch.arange(x.numel(), dtype=F64)
    expected = cols * torch.sqrt((k + 0.5) / f)
    assert x.numel() == 32  # pi f u^2 reaches 31.5 pi at the last column
    assert torch.allclose(x, expected, atol=0.05)
    # local frequency from the spacing of successive crossings (half periods), in cycles per pixel
    mid = 0.5 * (x[1:] + x[:-1])
    local = 0.5 / (x[1:] - x[:-1])
    assert torch.allclose(local[5:], f * mid[5:] / cols**2, rtol=0.05)  # crossings are good to ~0.05 px
    # contrast falls linearly down the rows: amplitude of row y is (H - y) / H
    amp = 0.5 * (r.amax(dim=1) - r.amin(dim=1)) / 0.5
    assert torch.allclose(amp, (8 - torch.arange(8, dtype=F64)) / 8, atol=2e-3)


def _fit_edge(r, dark):
    cov = (r - dark) / (1 - dark)
    ys, xs = [], []
    rows = r.shape[0]
    for i in range(rows):
        c = _crossings(cov[i], 0.5)
        if c.numel() == 1:
            ys.append(i - (rows - 1) / 2)
            xs.append(c.item() - (r.shape[1] - 1) / 2)
    slope, intercept = np.polyfit(ys, xs, 1)
    return slope, intercept


@pytest.mark.parametrize("angle", [5.0, -10.0, 30.0, 0.0])
def test_slanted_edge_angle(angle):
    s = sg.slanted_edge(64, angle, dark_level=0.2, dtype=F64)
    r = _refl(s)
    slope, intercept = _fit_edge(r, 0.2)
    assert math.degrees(math.atan(-slope)) == pytest.approx(angle, abs=0.02)
    assert abs(intercept) < 0.02  # through the image centre
    # exact box-pixel coverage: a line through the centre splits the square image into equal areas
    assert ((r - 0.2) / 0.8).mean().item() == pytest.approx(0.5, abs=1e-12)
    assert r.min().item() == pytest.approx(0.2) and r.max().item() == pytest.approx(1.0)
    assert r[:, 0].max() < 0.2 + 1e-12 and r[:, -1].min() > 1 - 1e-12  # dark left, bright right


def test_slanted_edge_pixel_coverage_against_supersampling():
    r = (_refl(sg.slanted_edge(12, 23.0, dark_level=0.0, dtype=F64)))
    n = 200  # 200 x 200 point samples per pixel
    off = (torch.arange(n, dtype=F64) + 0.5) / n - 0.5
    t = math.radians(23.0)
    for i, j in [(5, 5), (6, 6), (4, 7), (7, 4), (5, 6)]:
        y = i - 5.5 + off[:, None]
        x = j - 5.5 + off[None, :]
        frac = ((x * math.cos(t) + y * math.sin(t)) > 0).double().mean().item()
        assert r[i, j].item() == pytest.approx(frac, abs=2e-3)


# ---------------------------------------------------------------------------------------------
# Periodic patterns


def test_point_array_spacing():
    r = _refl(sg.point_array((40, 50), 8, point_size=2, dtype=F64))
    rows, cols = torch.nonzero(r > 0.5, as_tuple=True)
    ur, uc = torch.unique(rows), torch.unique(cols)
    # ISETCam: points at round(8 / 2) = 4, 12, ... (1-based) = 3, 11, ... (0-based), widened to 2 pixels by
    # conv2(d, ones(2), 'same'): rows 2-3, 10-11, ... (before 2026-11-30: 4-5, 12-13, ..., one pixel off)
    assert ur.tolist() == [2, 3, 10, 11, 18, 19, 26, 27, 34, 35]
    assert torch.equal(uc[::2].diff(), torch.full((5,), 8))
    assert int((r > 0.5).sum()) == 5 * 6 * 4
    assert r[r < 0.5].abs().max() == 0  # black background


def test_grid_lines_period():
    r = _refl(sg.grid_lines(48, 12, line_width=2, dtype=F64))
    full_rows = torch.nonzero((r > 0.5).all(dim=1)).flatten()
    full_cols = torch.nonzero((r > 0.5).all(dim=0)).flatten()
    # ISETCam: d((round(12 / 2):12:48) + ii, :) = 1, ii = 0, 1 (1-based rows 6-7, 18-19, ...) = 0-based 5-6, 17-18
    assert full_rows.tolist() == [5, 6, 17, 18, 29, 30, 41, 42]
    assert torch.equal(full_rows, full_cols)
    assert torch.equal(r[5:35], r[17:47])  # periodic with the spacing
    assert int((r > 0.5).sum()) == 48 * 48 - (48 - 8) ** 2


def test_checkerboard_periods():
    r = _refl(sg.checkerboard((24, 32), 4, dtype=F64))
    assert r[0, 0] == 0 and r[0, 4] == 1 and r[4, 0] == 1
    assert torch.equal(r[:, 8:], r[:, :-8]) and torch.equal(r[8:], r[:-8])  # period 2 squares
    assert torch.equal(r[:, 4:], 1 - r[:, :-4]) and torch.equal(r[4:], 1 - r[:-4])  # half period inverts
    assert r.mean().item() == 0.5
    spec = torch.fft.rfft(r[0] - r[0].mean()).abs()
    assert spec.argmax().item() == 32 // 8  # fundamental: 4 cycles per 32 columns


# ---------------------------------------------------------------------------------------------
# Radial patterns


def test_star_symmetry_and_spokes():
    n = 24
    r = _refl(sg.star(64, n, dtype=F64))
    assert torch.allclose(r, r.rot90(1, (0, 1)), atol=1e-9)  # 90 deg is a multiple of 360 / 24
    assert torch.allclose(r.flip(0), 1 - r, atol=1e-9)  # mirror about the horizontal axis swaps bright/dark
    y, x = torch.meshgrid(torch.arange(64, dtype=F64) - 31.5, torch.arange(64, dtype=F64) - 31.5, indexing="ij")
    ring = (torch.hypot(x, y) - 28).abs() < 0.5
    theta = torch.atan2(-y[ring], x[ring])
    v = r[ring][theta.argsort()]
    changes = ((v[1:] > 0.5) != (v[:-1] > 0.5)).sum() + ((v[0] > 0.5) != (v[-1] > 0.5))
    assert changes.item() == 2 * n
    s = _refl(sg.star(32, 8, profile="sine", dtype=F64))
    assert s.mean().item() == pytest.approx(0.5, abs=1e-12)


def test_zone_plate_local_frequency():
    size, f = 65, 0.5
    r = _refl(sg.zone_plate(size, f, dtype=F64))
    radius = size / 2
    assert torch.allclose(r, r.T, atol=1e-12) and torch.allclose(r, r.rot90(1, (0, 1)), atol=1e-12)
    row = r[32, 32:]  # centre row, from the centre outwards (r = x)
    x = _crossings(row, 0.5)
    k = torch.arange(x.numel(), dtype=F64)
    expected = torch.sqrt(radius * (k + 0.5) / f)
    low = expected < radius / 2  # where the local frequency is below 0.25 cycles / pixel
    assert torch.allclose(x[low], expected[low], atol=0.05)
    mid = 0.5 * (x[1:] + x[:-1])
    local = 0.5 / (x[1:] - x[:-1])
    sel = mid < radius / 2
    assert torch.allclose(local[sel], f * mid[sel] / radius, rtol=0.03)


# ---------------------------------------------------------------------------------------------
# HDR chart


def test_hdr_chart_range():
    s = sg.hdr_chart(decades=6, steps_per_decade=2, patch_size=3, dtype=F64)
    lum = s.luminance()[0, 0]
    assert lum.shape == (3, 39)
    patches = lum[1, 1::3]
    assert (patches.max() / patches.min()).item() == pytest.approx(1e6, rel=1e-9)
    assert torch.allclose(patches[:-1] / patches[1:], torch.full((12,), 10**0.5, dtype=F64), rtol=1e-9)
    assert s.mean_luminance().item() == pytest.approx(100.0, rel=1e-9)


# ---------------------------------------------------------------------------------------------
# Errors


@pytest.mark.parametrize("call", [
    lambda: sg.uniform("D65", -4),
    lambda: sg.uniform("D65", 0),
    lambda: sg.uniform("D65", (4, -1)),
    lambda: sg.uniform("D65", (4, 4, 4)),
    lambda: sg.ramp(-3),
    lambda: sg.ramp(8, "cubic"),
    lambda: sg.ramp(8, "exponential", dynamic_range=1.0),
    lambda: sg.ramp(8, "exponential", dark_level=5.0),  # (the kind's unused argument had been taken unchecked)
    lambda: sg.ramp(8, "linear", dynamic_range=-3.0),
    lambda: sg.frequency_sweep(16, 9.0),
    lambda: sg.frequency_sweep(16, -1.0),
    lambda: sg.slanted_edge(16, 90.0),
    lambda: sg.slanted_edge(16, -95.0),
    lambda: sg.slanted_edge(16, float("nan")),
    lambda: sg.slanted_edge(16, 5.0, dark_level=1.0),
    lambda: sg.point_array(16, 0),
    lambda: sg.point_array(16, 4, point_size=5),
    lambda: sg.grid_lines(16, 4, line_width=4),
    lambda: sg.star(16, 1),
    lambda: sg.star(16, 8, profile="triangle"),
    lambda: sg.checkerboard(16, 16),
    lambda: sg.zone_plate(16, 0.6),
    lambda: sg.hdr_chart(0),
    lambda: sg.monochromatic(555.0, 4, wavelengths=W10),
    lambda: sg.monochromatic(900.0, 4),
    lambda: sg.monochromatic(-5.0, 4),
    lambda: sg.uniform("D65", 4, mean_luminance_cd_m2=-1.0),
])
def test_bad_input_value_error(call):
    with pytest.raises(ValueError):
        call()


def test_error_messages_name_the_argument():
    with pytest.raises(ValueError, match=r"size: expected an integer >= 1, got -4"):
        sg.checkerboard(-4)
    # 46 decades made float32's darkest patches exactly 0 (the ratio 10^46 infinite); 'no' was a True ramp
    with pytest.raises(ValueError, match=r"decades: 46 decades reach below torch.float32's smallest"):
        sg.hdr_chart(46, 1, 1, dtype=torch.float32)
    with pytest.raises(TypeError, match="contrast_ramp: expected True or False"):
        sg.frequency_sweep(16, contrast_ramp="no")
    with pytest.raises(ValueError, match=r"angle_deg: expected a value < 90.0, got 90.0"):
        sg.slanted_edge(16, 90)
    with pytest.raises(ValueError, match=r"spectrum: .*unknown illuminant 'D6x5'"):
        sg.uniform("D6x5")
    with pytest.raises(ValueError, match="illuminant: .*unknown illuminant"):
        sg.star(16, illuminant="sunshine")
    with pytest.raises(TypeError, match="angle_deg"):
        sg.slanted_edge(16, "steep")
    with pytest.raises(TypeError, match="size"):
        sg.zone_plate(16.5)
    with pytest.raises(TypeError, match="dtype"):
        sg.uniform("D65", 4, dtype=torch.int32)
