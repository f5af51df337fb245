"""The lazy (Fourier-domain) ISETCam-mode optical image of a factored scene: the sensor projects it on its K QE
weightings (K inverse FFTs) instead of reading the L-plane cube. Everything is checked against the dense
``compute_oi`` path (itself checked against an independent NumPy oiCompute and ISETCam's own case in
``test_isetcam_parity.py``), in float64, to float rounding."""


import numpy as np
import pytest
import torch
from shared_paths import PARITY_CASE

from isettorch.io.isetcam import case_sensor, read_parity_case
from isettorch.optics import DiffractionLimitedOptics, isetcam
from isettorch.optics.optical_image import FourierFactors
from isettorch.scene import Scene
from isettorch.sensor import ISETCAM_CONVENTIONS, Sensor

CASE = PARITY_CASE
WAVE = torch.tensor([420.0, 480.0, 540.0, 600.0, 660.0], dtype=torch.float64)


def _factored(b=1, seed=5):
    """A rank-2 radiance: two non-negative maps (one with a dark bar, 5 % of the max), each with its spectrum."""
    g = torch.Generator().manual_seed(seed)
    maps = torch.rand(b, 2, 21, 26, generator=g, dtype=torch.float64)
    maps[:, 0, 8:12] *= 0.05
    spectra = torch.rand(b, 2, 5, generator=g, dtype=torch.float64) * 1e16 + 1e15
    return maps, spectra


def _sensor(oi, **kw):
    s = Sensor.preset("isetcam_default", rows=16, cols=20, read_noise_v=0.0, dark_current_e_per_s=0.0,
                      shot_noise="off", exposure_s=0.01, pixel_size_m=float(oi.sample_spacing_m[0]) * 1.3,
                      **ISETCAM_CONVENTIONS, **kw)
    return s.to(torch.float64)


@pytest.mark.parametrize("offaxis", ["cos4th", "skip"])
def test_lazy_oi_equals_dense(offaxis):
    """Dense read (the abs-ed cube), projections and geometry of the lazy OI = those of the dense OI."""
    maps, spectra = _factored(b=2)
    args = (WAVE, [12.0, 7.0], 1.5, [2.8, 8.0], 4e-3, np.linspace(0.7, 1.0, 5))
    dense = isetcam.compute_oi_factored(maps, spectra, *args, offaxis=offaxis)
    lazy = isetcam.compute_oi_factored(maps, spectra, *args, offaxis=offaxis, lazy=True)
    assert lazy.is_factored and isinstance(lazy.factors, isetcam.IsetcamFourierFactors)
    assert lazy.__dict__.get("_photons") is None
    for k in ("sample_spacing_m", "hfov_deg", "image_distance_m", "f_number", "focal_length_m"):
        assert torch.equal(getattr(lazy, k), getattr(dense, k)), k
    assert (lazy.pad_rows, lazy.pad_cols, lazy.height, lazy.width) == (dense.pad_rows, dense.pad_cols,
                                                                      dense.height, dense.width)
    w = torch.rand(5, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    proj = lazy.project(w)  # K = 3 inverse FFTs, before any dense read
    ref = dense.project(w)
    torch.testing.assert_close(proj, ref, rtol=1e-12, atol=1e-12 * float(ref.abs().max()))
    # ISETCam's abs is the identity here: the blurred irradiance before it is positive everywhere
    assert float(FourierFactors.dense(lazy.factors).min()) > 0
    torch.testing.assert_close(lazy.photons, dense.photons, rtol=1e-12, atol=1e-12 * float(dense.photons.max()))
    # crop and select keep the lazy form and its abs
    c = lazy.crop(3, 4, 10, 12)
    assert isinstance(c.factors, isetcam.IsetcamFourierFactors)
    torch.testing.assert_close(c.photons, dense.photons[:, :, 3:13, 4:16], rtol=1e-12, atol=0)
    torch.testing.assert_close(lazy[1].photons, dense.photons[1:2], rtol=1e-12, atol=0)


def test_dense_read_keeps_isetcams_abs():
    """A point on a black field: ISETCam's truncated OTF rings below zero; the lazy OI's dense read is the
    abs-ed cube of compute_oi (FORMAT.md 4.4), and its projection is that of the signed irradiance (documented:
    the lazy form equals ISETCam's only where the blurred irradiance is non-negative)."""
    maps = torch.zeros(1, 1, 17, 17, dtype=torch.float64)
    maps[0, 0, 8, 8] = 1.0
    spectra = torch.full((1, 1, 5), 1e16, dtype=torch.float64)
    args = (WAVE, 2.0, 1.5, 2.8, 4e-3)
    dense = isetcam.compute_oi_factored(maps, spectra, *args)
    lazy = isetcam.compute_oi_factored(maps, spectra, *args, lazy=True)
    signed = FourierFactors.dense(lazy.factors)
    assert float(signed.min()) < -1e-3 * float(signed.max())  # the rings exist
    w = torch.ones(5, 1, dtype=torch.float64)
    torch.testing.assert_close(lazy.project(w), (signed * w[:, 0, None, None]).sum(1, keepdim=True))
    torch.testing.assert_close(lazy.photons, dense.photons, rtol=1e-12, atol=1e-12 * float(dense.photons.max()))
    torch.testing.assert_close(lazy.photons, signed.abs(), rtol=1e-12, atol=0)


def test_optics_module_returns_lazy_oi_and_sensor_matches_dense():
    """DiffractionLimitedOptics(pad_mode='isetcam') on a factored scene returns the lazy OI; the ISETCam sensor
    (pre-blur + bilinear point sampling: linear and wavelength-independent, so projecting first is exact)
    gives the same volts and DN as on the dense scene's OI."""
    maps, spectra = _factored()
    scene = Scene.from_factors(maps, spectra, WAVE, hfov_deg=12.0, distance_m=1.5)
    dscene = Scene(torch.einsum("bjhw,bjl->blhw", maps, spectra), WAVE, hfov_deg=12.0, distance_m=1.5)
    optics = DiffractionLimitedOptics(f_number=2.8, focal_length_m=4e-3, pad_mode="isetcam").to(torch.float64)
    lazy, dense = optics(scene), optics(dscene)
    assert lazy.is_factored and not dense.is_factored
    for bits in (None, 10):
        sensor = _sensor(dense, adc_bits=bits, output_units="volts" if bits is None else "dn")
        a, b = sensor(lazy, noise=False).data, sensor(dense, noise=False).data
        assert float(b.max()) > 0.05 * (1.0 if bits is None else 1024)  # a real signal, not clipped to 0
        torch.testing.assert_close(a, b, rtol=1e-12, atol=0 if bits is None else 1.0)
        if bits is not None:  # DN: a rounding boundary may flip by one count at most
            assert float((a != b).float().mean()) < 0.01
    assert lazy.__dict__.get("_photons") is None  # the sensor never formed the cube
    win = optics(scene, crop=(2, 3, 15, 20))
    torch.testing.assert_close(win.photons, dense.photons[:, :, 2:17, 3:23], rtol=1e-12, atol=0)


def test_gradients_through_the_lazy_projection():
    """The sensor's projection of the lazy OI is differentiable in the scene's maps and spectra (gradcheck,
    float64), and its gradient equals that of the dense path."""
    maps, spectra = _factored()
    maps, spectra = maps[:, :, :6, :7].clone(), spectra[:, :, :2].clone() / 1e16
    w = torch.tensor([[0.3, 1.0], [0.8, 0.2]], dtype=torch.float64)
    args = (WAVE[:2], 12.0, 1.5, 2.8, 4e-3)

    def lazy(m, s):
        return isetcam.compute_oi_factored(m, s, *args, lazy=True).project(w)

    def dense(m, s):
        return isetcam.compute_oi_factored(m, s, *args).project(w)

    m, s = maps.requires_grad_(True), spectra.requires_grad_(True)
    assert torch.autograd.gradcheck(lazy, (m, s), eps=1e-6, atol=1e-7)
    ga = torch.autograd.grad(lazy(m, s).square().sum(), (m, s))
    gb = torch.autograd.grad(dense(m, s).square().sum(), (m, s))
    for x, y in zip(ga, gb):
        torch.testing.assert_close(x, y, rtol=1e-10, atol=1e-12 * float(y.abs().max()))


@pytest.mark.skipif(not CASE.exists(), reason="shared ISETCam parity case not present")
def test_parity_case_through_the_lazy_path():
    """ISETCam's Macbeth case as a factored scene (maps = the L planes, spectra = the identity): the lazy OI and
    the case's sensor give the dense path's volts to float rounding, and ISETCam's own volts within the parity
    bound (max relative error 1e-5 over pixels above 1 % of the max, as ``isettorch parity``)."""
    case = read_parity_case(CASE)
    photons = torch.as_tensor(case["scene_photons"], dtype=torch.float64)
    wave = torch.as_tensor(case["wavelengths_nm"], dtype=torch.float64).reshape(-1)
    nl = wave.numel()
    kw = dict(hfov_deg=float(case["scene_hfov_deg"]), distance_m=float(case["scene_distance_m"]))
    scene = Scene.from_factors(photons[None], torch.eye(nl, dtype=torch.float64)[None], wave, **kw)
    optics = DiffractionLimitedOptics(f_number=float(case["optics_f_number"]),
                                      focal_length_m=float(case["optics_focal_length_m"]),
                                      pad_mode="isetcam").to(torch.float64)
    lazy, dense = optics(scene), optics(Scene(photons, wave, **kw))
    assert float(FourierFactors.dense(lazy.factors).min()) > 1e-4 * float(dense.photons.max())  # abs = identity
    sensor = case_sensor(case).to(torch.float64)
    a, b = sensor(lazy, noise=False).data[0, 0], sensor(dense, noise=False).data[0, 0]
    torch.testing.assert_close(a, b, rtol=1e-11, atol=0)
    ref = torch.as_tensor(case["sensor_volts"], dtype=torch.float64)
    m = ref > 0.01 * ref.max()
    assert float(((a - ref).abs()[m] / ref[m]).max()) <= 1e-5
