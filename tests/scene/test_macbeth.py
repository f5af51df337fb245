"""Macbeth ColorChecker scene: colorimetry against colour-science, layout, ISETCam parity."""


import colour
import numpy as np
import pytest
import torch
from shared_paths import PARITY_CASE

from isettorch import spectral
from isettorch.scene import macbeth, macbeth_patch_names, macbeth_patch_slices, macbeth_reflectances

PARITY = PARITY_CASE
SOURCE = colour.characterisation.SDS_COLOURCHECKERS["BabelColor Average"]
CMFS = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]


def _patch_xyz_relative(scene, patch_size):
    """Mean XYZ of each patch relative to the white (Y of the illuminant = 100) [24, 3]."""
    xyz = scene.xyz()[0]
    white_y = spectral.xyz(scene.illuminant_photons[0], scene.wavelengths_nm, dim=0)[1]
    return torch.stack([xyz[:, r, c].mean(dim=(1, 2)) for r, c in macbeth_patch_slices(patch_size)]) / white_y * 100


@pytest.mark.parametrize("start,stop,step,linear", [(400, 700, 10, False), (380, 730, 5, True), (400, 700, 1, True)])
def test_xyz_matches_colour_science(start, stop, step, linear):
    """colour.sd_to_XYZ 'Integration' (rectangle rule, k = 100 / sum(S ybar)) on the same grid and data.

    10 nm: the data's native samples (no interpolation anywhere, CMFs and D65 are exact samples of their
    1 nm / 5 nm tables). 5 nm and 1 nm: the reflectances (and at 1 nm D65) are interpolated, so colour-science
    is told to interpolate linearly too, as isettorch does (colour-science's default is Sprague).
    """
    shape = colour.SpectralShape(start, stop, step)
    w = torch.arange(start, stop + step / 2, step, dtype=torch.float64)
    scene = macbeth("D65", patch_size=2, wavelengths=w, dtype=torch.float64)
    ours = _patch_xyz_relative(scene, 2)
    cmfs = CMFS.copy().align(shape)
    ill = colour.SDS_ILLUMINANTS["D65"].copy()
    if linear:
        ill = colour.SpectralDistribution(ill.values, ill.wavelengths, interpolator=colour.LinearInterpolator)
    ill = ill.align(shape)
    ref = []
    for name in macbeth_patch_names():
        sd = SOURCE[name].copy()
        if linear:
            sd = colour.SpectralDistribution(sd.values, sd.wavelengths, interpolator=colour.LinearInterpolator)
        sd = sd.align(shape)
        ref.append(colour.sd_to_XYZ(sd, cmfs, ill, method="Integration"))
    ref = torch.tensor(np.array(ref))
    rel = ((ours - ref).abs() / ref.abs()).max().item()
    assert rel < 1e-3, rel
    assert rel < 1e-9  # measured: the integration rules coincide exactly (float64 rounding)


def test_layout_and_reflectance():
    s = macbeth(patch_size=4, dtype=torch.float64)
    assert s.photons.shape == (1, 31, 16, 24)
    names = macbeth_patch_names()
    assert names[0] == "dark skin" and names[18].startswith("white") and names[23].startswith("black")
    refl = macbeth_reflectances(s.wavelengths_nm)
    got = s.reflectance()[0]
    for k, (r, c) in enumerate(macbeth_patch_slices(4)):
        assert torch.allclose(got[:, r, c], refl[k][:, None, None].expand(-1, 2, 2), rtol=1e-12)
    # reflectance data are the colour-science values at the native 10 nm samples
    assert torch.allclose(refl[0], torch.tensor(SOURCE["dark skin"].values[2:33]), rtol=1e-12)
    # the white patch is brightest, black darkest
    lum = torch.stack([s.luminance()[0, 0, r, c].mean() for r, c in macbeth_patch_slices(4)])
    assert lum.argmax().item() == 18 and lum.argmin().item() == 23


def test_mean_luminance_and_dtypes():
    for dt in (torch.float32, torch.float64):
        s = macbeth(patch_size=2, dtype=dt)
        assert s.dtype == dt
        assert abs(s.mean_luminance().item() - 100) < 1e-5 * 100
    s = macbeth(patch_size=2, mean_luminance_cd_m2=7.0, dtype=torch.float64)
    assert s.mean_luminance().item() == pytest.approx(7.0, rel=1e-12)


def test_tensor_illuminant_equals_name():
    w = spectral.default_wavelengths(dtype=torch.float64)
    a = macbeth("A", patch_size=2, dtype=torch.float64)
    b = macbeth(spectral.illuminant("A", w) * 3.7, patch_size=2, dtype=torch.float64)
    assert torch.allclose(a.photons, b.photons, rtol=1e-12)


def test_reflectance_extrapolation_holds_end_values():
    r = macbeth_reflectances(torch.tensor([360.0, 380.0, 730.0, 800.0], dtype=torch.float64))
    assert torch.equal(r[:, 0], r[:, 1]) and torch.equal(r[:, 2], r[:, 3])


def test_patch_slices():
    sl = macbeth_patch_slices(16)
    assert len(sl) == 24
    assert sl[0] == (slice(4, 12), slice(4, 12))
    assert sl[23] == (slice(52, 60), slice(84, 92))
    assert macbeth_patch_slices(1)[7] == (slice(1, 2), slice(1, 2))


@pytest.mark.skipif(not PARITY.exists(), reason="ISETCam parity data not available")
def test_isetcam_layout_parity():
    """ISETCam's macbeth d65 (its own reflectance set): same 64x96 layout of uniform 16-px patches, same FOV
    and luminance; patch chromaticities agree to 0.05 in xy at worst (the saturated blue; ISETCam's own
    macbethChart reflectances are a different measurement) and to 0.01 in the median."""
    d = np.load(PARITY, allow_pickle=False)
    w = torch.from_numpy(d["wavelengths_nm"]).double()
    ref = torch.from_numpy(d["scene_photons"].astype(np.float64))
    s = macbeth(wavelengths=w, dtype=torch.float64)
    assert s.photons.shape[1:] == ref.shape
    assert s.hfov_deg.item() == pytest.approx(float(d["scene_hfov_deg"]))
    assert s.mean_luminance().item() == pytest.approx(float(d["scene_mean_luminance_cdm2"]), rel=1e-6)
    xyz_ref = spectral.xyz(ref, w, dim=0)
    xyz_ours = s.xyz()[0]
    diffs = []
    for r, c in macbeth_patch_slices(16):
        a, b = xyz_ref[:, r, c].mean(dim=(1, 2)), xyz_ours[:, r, c].mean(dim=(1, 2))
        diffs.append((a[:2] / a.sum() - b[:2] / b.sum()).abs().max())
    diffs = torch.stack(diffs)
    assert diffs.max() < 0.05 and diffs.median() < 0.01, diffs
    # patch edges line up: the ISETCam image is constant inside each of our patches
    for r, c in macbeth_patch_slices(16, fraction=1.0):
        block = ref[:, r, c]
        assert torch.allclose(block, block[:, :1, :1].expand_as(block), rtol=1e-6)


def test_errors():
    with pytest.raises(ValueError, match="illuminant"):
        macbeth("D99x")
    with pytest.raises(ValueError, match="patch_size"):
        macbeth(patch_size=0)
    with pytest.raises(TypeError, match="patch_size"):
        macbeth(patch_size=2.5)
    with pytest.raises(ValueError, match="illuminant"):
        macbeth(torch.ones(5))
    with pytest.raises(ValueError, match="illuminant"):
        macbeth(-torch.ones(31))
    with pytest.raises(ValueError, match="wavelengths"):
        macbeth(wavelengths=torch.tensor([500.0, 400.0]))
    with pytest.raises(ValueError, match="fraction"):
        macbeth_patch_slices(16, fraction=0)
