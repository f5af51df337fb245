"""Bad input to the public API is refused with an error naming the argument, not computed into a wrong result (an
audit of about 700 bad-input probes, 2026-12-02). Each case says in brackets what happened before."""

import numpy as np
import pytest
import torch

from isettorch import metrics, scene, spectral
from isettorch.data import seed_for, spectra
from isettorch.data.scenes import generate_scene
from isettorch.io import write_image
from isettorch.isp import ImageProcessor, demosaic, gray_world_gains, illuminant_gains, reflectance_set
from isettorch.isp.demosaicing import demosaic_bilinear, demosaic_malvar2004, demosaic_menon2007
from isettorch.optics import OpticalImage, WavefrontOptics
from isettorch.sensor import RawImage, Sensor, filter_set, ir_cut_filter, photodiode_qe

F64 = torch.float64
W = torch.arange(400.0, 701.0, 10.0, dtype=F64)


def _nan_mosaic():
    raw = torch.rand(1, 1, 8, 8, dtype=F64, generator=torch.Generator().manual_seed(0))
    raw[0, 0, 3, 4] = float("nan")
    return raw


def _oi():
    return OpticalImage(torch.full((1, 31, 4, 4), 1e14, dtype=F64), W, sample_spacing_m=2.8e-6)


@pytest.mark.parametrize("call, exc, match", [
    # 8-bit codes read as [0, 1] values (grey 200 at Y = 293,057)
    (lambda: metrics.srgb_to_xyz(torch.full((1, 3, 2, 2), 200, dtype=torch.uint8)), TypeError, "srgb: expected a "
     "floating-point tensor in \\[0, 1\\] units"),
    (lambda: metrics.xyz_to_lab(torch.ones(1, 3, 2, 2, dtype=torch.complex64)), TypeError, "xyz: expected a real"),
    # a [3] input_max for one image returned three images; NaN a NaN image
    (lambda: ImageProcessor(sensor_to_xyz=torch.eye(3)).from_demosaiced(torch.rand(1, 3, 4, 4),
                                                                        input_max=torch.tensor([1.0, 0.5, 0.25])),
     ValueError, "input_max: expected 1 value"),
    (lambda: ImageProcessor(sensor_to_xyz=torch.eye(3)).from_demosaiced(torch.rand(1, 3, 4, 4),
                                                                        input_max=torch.tensor([float("nan")])),
     ValueError, "input_max: expected finite"),
    (lambda: ImageProcessor(sensor_to_xyz=torch.eye(3)).from_demosaiced(torch.rand(1, 3, 4, 4), input_max=-1.0),
     ValueError, "input_max: expected raw maxima >= 0"),  # (clamped to 0: a black image)
    (lambda: ImageProcessor(sensor_to_xyz=torch.eye(3))(torch.rand(1, 1, 8, 8)), TypeError,
     "raw: expected a RawImage"),  # ('Tensor' object has no attribute 'white_level')
    # per-item levels were not checked: white below black gave NaN pixels, 3 levels for 2 items a broadcast error
    (lambda: RawImage(torch.rand(2, 1, 8, 8), "volts", "GRBG", black_level=0.5, white_level=torch.tensor([0.0, 0.0])),
     ValueError, "white_level: expected a level above black_level"),
    (lambda: RawImage(torch.rand(2, 1, 8, 8), "volts", "GRBG", white_level=torch.tensor([1.0, 1.0, 1.0])),
     ValueError, "white_level: expected a number or a \\[B\\] tensor of 1 or 2"),
    (lambda: RawImage(torch.rand(2, 1, 8, 8), "volts", "GRBG", black_level=torch.tensor([0.1, float("nan")]),
                      white_level=1.0), ValueError, "black_level: expected finite levels"),
    (lambda: RawImage(torch.rand(2, 1, 8, 8), "volts", "GRBG", black_level=torch.tensor([0.1, 0.9]),
                      white_level=torch.tensor([1.0, 0.8])), ValueError, "white_level: expected a level above"),
    # integer dtypes truncated the tables to 0 and 1
    (lambda: spectral.cmfs(W, dtype=torch.long), ValueError, "dtype: expected torch.float32 or torch.float64"),
    (lambda: metrics.macbeth_reference_xyz(dtype=torch.long), ValueError, "dtype: expected torch.float32"),
    (lambda: filter_set("isetcam_rgb", W, dtype=torch.long), ValueError, "dtype: expected torch.float32"),
    (lambda: ir_cut_filter(W, dtype=torch.int32), ValueError, "dtype: expected torch.float32"),
    (lambda: reflectance_set("macbeth", W, dtype=torch.long), ValueError, "dtype: expected torch.float32"),
    (lambda: spectra.measured_reflectances(W, dtype=torch.long), ValueError, "dtype: expected torch.float32"),
    (lambda: spectra.reflectance_basis(W, dtype=torch.long), ValueError, "dtype: expected torch.float32"),
    # flags read by truthiness: clip='no' clipped, textiles='no' took the textile weights
    (lambda: metrics.xyz_to_srgb(torch.ones(1, 3, 1, 1), clip="no"), TypeError, "clip: expected True or False"),
    (lambda: metrics.delta_e_94(torch.ones(1, 3), torch.ones(1, 3), dim=-1, textiles="no"), TypeError,
     "textiles: expected True or False"),
    (lambda: write_image("/nonexistent/x.png", torch.full((3, 2, 2), 1.5), clip="no"), TypeError,
     "clip: expected True or False"),
    (lambda: write_image("/nonexistent/x.png", torch.full((3, 2, 2), 0.5), clip="no"), TypeError,
     "clip: expected True or False"),  # (values in range: the flag is checked all the same)
    (lambda: ImageProcessor(clip_negative_xyz="no"), TypeError, "clip_negative_xyz: expected True or False"),
    (lambda: demosaic_bilinear(torch.rand(1, 1, 4, 4), normalize_border="no"), TypeError, "normalize_border"),
    (lambda: metrics.ssim(torch.rand(1, 3, 16, 16), torch.rand(1, 3, 16, 16), return_map="no"), TypeError,
     "return_map"),
    (lambda: metrics.pixel_snr(400.0, db="no"), TypeError, "db: expected True or False"),
    (lambda: metrics.pixel_snr(400.0, shot="no"), TypeError, "shot: expected True or False"),
    # bools as numbers: a 1 cd/m^2 scene, a data range of 1, 1 diopter, a QE of 1
    (lambda: scene.uniform(size=4, mean_luminance_cd_m2=True), TypeError, "mean_luminance_cd_m2: expected a number"),
    (lambda: metrics.psnr(torch.rand(1, 3, 4, 4), torch.rand(1, 3, 4, 4), data_range=True), TypeError,
     "data_range: expected a number"),
    (lambda: WavefrontOptics(zernike_um=torch.zeros(15), defocus_diopters=True), TypeError,
     "defocus_diopters: expected a number"),
    (lambda: photodiode_qe(W, True), ValueError, "value: expected a quantum efficiency"),
    # the demosaic functions called directly spread one NaN sample to 23-73 outputs (demosaic() refused it)
    (lambda: demosaic_bilinear(_nan_mosaic()), ValueError, "raw: expected finite values, found 1"),
    (lambda: demosaic_malvar2004(_nan_mosaic()), ValueError, "raw: expected finite values, found 1"),
    (lambda: demosaic_menon2007(_nan_mosaic()), ValueError, "raw: expected finite values, found 1"),
    (lambda: demosaic(_nan_mosaic(), "RGGB", method="menon2007"), ValueError, "raw: expected finite values"),
    # a 1-D vignetting profile was applied along the columns
    (lambda: Sensor(rows=4, cols=4, vignetting=torch.tensor([1.0, 0.5, 0.25, 0.1])), ValueError,
     "vignetting: expected a scalar or a \\[rows, cols\\]"),
    # exposure_ev was silently dropped beside an explicit exposure_s
    (lambda: Sensor(rows=4, cols=4)(_oi(), exposure_s=0.01, exposure_ev=3.0, noise=False), ValueError,
     "exposure_ev: compensates the sensor's fixed or auto exposure"),
    # seeds: 1.5, "1" and True were seed 1, -1 was 2^64 - 1
    (lambda: seed_for(1.5, 0), ValueError, "seed: expected an integer"),
    (lambda: seed_for(True, 0), ValueError, "seed: expected an integer"),
    (lambda: seed_for(-1, 0), ValueError, "seed: expected an integer in \\[0, 2\\*\\*64\\)"),
    (lambda: seed_for(1, 0.5), ValueError, "index: expected an integer"),
    # an out-of-range index failed in a reshape (factored) or as 'photons: expected a non-empty' (dense)
    (lambda: scene.macbeth(patch_size=4)[5], IndexError, "index: 5 is out of range for a batch of 1"),
    (lambda: scene.macbeth(patch_size=4).to_dense()[-2], IndexError, "index: -2 is out of range"),
    (lambda: scene.macbeth(patch_size=4).mean_spectrum(slice(100, 200)), ValueError,
     "rows: slice\\(100, 200, None\\) selects no pixels"),  # (NaN)
    (lambda: gray_world_gains(torch.rand(1, 3, 4, 4) + 0.1, no_signal="clip"), ValueError,
     "no_signal: expected one of"),  # (a balanced image: checked all the same)
    (lambda: illuminant_gains(torch.rand(1, 3, 4, 4) + 0.1, "gray_world", gains=[1.0, 2.0, 3.0]), ValueError,
     "gains: only illuminant correction 'manual' uses gains"),  # (ignored)
    # low-level crashes
    (lambda: spectral.resample(torch.ones(2), [400.0, 500.0], [450.0], dim=3), ValueError,
     "dim: expected the spectral axis of values"),  # (IndexError)
    (lambda: spectral.luminance(torch.rand(31, 5), W), ValueError, "dim: expected the spectral axis of photons"),
    (lambda: spectral.resample_rows(torch.rand(3, 4), torch.linspace(400, 700, 4).expand(2, 4), torch.tensor([500.])),
     ValueError, "src_nm: expected one grid per row"),
    (lambda: metrics.psnr(torch.rand(0, 3, 8, 8), torch.rand(0, 3, 8, 8)), ValueError, "image: expected a non-empty"),
    (lambda: scene.from_rgb(torch.rand(0, 3, 4, 4)), ValueError, "rgb: expected a non-empty image"),
    (lambda: generate_scene(0, size=16), ValueError, "size: expected \\(height, width\\)"),  # ('cannot unpack')
])
def test_bad_input_is_refused_naming_the_argument(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


def test_what_the_checks_still_accept_computes_what_it_did():
    """The good inputs next to the refused ones: an integer grid's quadrature is the float grid's (its midpoint
    weights were truncated, 1.5 nm to 1: luminance 10.6 % low), one grid serves every row of resample_rows, a [1]
    vignetting is a scalar, [B] levels are per item, and a scene's index -1 is its last item."""
    wi = torch.tensor([400, 401, 403, 406])
    assert spectral.wavelength_weights(wi).tolist() == [1.0, 1.5, 2.5, 3.0]
    photons = torch.rand(4, 1, 1, dtype=F64, generator=torch.Generator().manual_seed(1)) * 1e16
    assert float(spectral.luminance(photons, wi)) == pytest.approx(float(spectral.luminance(photons, wi.double())),
                                                                   rel=1e-12)
    v = torch.rand(3, 4, dtype=F64, generator=torch.Generator().manual_seed(2))
    src, dst = torch.tensor([400.0, 450.0, 600.0, 700.0], dtype=F64), torch.tensor([420.0, 500.0, 650.0])
    expected = np.stack([np.interp(dst.numpy(), src.numpy(), row) for row in v.numpy()])
    np.testing.assert_allclose(spectral.resample_rows(v, src, dst).numpy(), expected, rtol=1e-12)
    a = Sensor(rows=4, cols=4, cfa="MONO", vignetting=torch.tensor([0.5]))(_oi(), noise=False, exposure_s=1e-3)
    b = Sensor(rows=4, cols=4, cfa="MONO", vignetting=0.5)(_oi(), noise=False, exposure_s=1e-3)
    assert torch.equal(a.data, b.data)
    raw = RawImage(torch.full((2, 1, 4, 4), 0.5, dtype=F64), "volts", "GRBG", black_level=torch.tensor([0.0, 0.25]),
                   white_level=torch.tensor([1.0]))
    torch.testing.assert_close(raw.normalized()[:, 0, 0, 0], torch.tensor([0.5, 1 / 3], dtype=F64))
    s = scene.Scene.cat([scene.macbeth(patch_size=4), scene.macbeth(patch_size=4).set_mean_luminance(50.0)])
    assert float(s[-1].mean_luminance()) == pytest.approx(50.0, rel=1e-5)
    assert float(s[0].mean_luminance()) == pytest.approx(100.0, rel=1e-5)
