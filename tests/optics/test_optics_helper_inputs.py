"""The optics helpers exported beside the modules refuse inputs that gave NaN, a negative spacing or a black image
(an optics audit of 2026-12-01), and options ISETCam's fixed computation would ignore."""

import math

import pytest
import torch

from isettorch.optics import DiffractionLimitedOptics, WavefrontOptics, analysis, geometry, otf_from_psf

X = torch.linspace(-1e-3, 1e-3, 5, dtype=torch.float64)[None]


@pytest.mark.parametrize("hfov, d_i, name", [(-10.0, 4e-3, "hfov_deg"), (200.0, 4e-3, "hfov_deg"),
                                             (180.0, 4e-3, "hfov_deg"), (math.nan, 4e-3, "hfov_deg"),
                                             (10.0, -4e-3, "image_distance_m"), (10.0, 0.0, "image_distance_m")])
def test_image_sample_spacing_refuses_a_field_or_distance_without_an_image(hfov, d_i, name):
    with pytest.raises(ValueError, match=name):
        geometry.image_sample_spacing(hfov, 10, d_i)
    with pytest.raises(ValueError, match=name):
        geometry.image_sample_spacing(torch.tensor([10.0, hfov], dtype=torch.float64), 10,
                                      torch.tensor([4e-3, d_i], dtype=torch.float64))


def test_image_sample_spacing_value():
    # 2 d_i tan(hfov / 2) / W (thin-lens image plane)
    assert float(geometry.image_sample_spacing(10.0, 100, 4e-3)) == pytest.approx(
        2 * 4e-3 * math.tan(math.radians(5.0)) / 100, rel=1e-14)


@pytest.mark.parametrize("n", [0.0, -2.0, math.nan, math.inf])
def test_camera_equation_refuses_f_numbers_without_a_lens(n):
    for paraxial in (False, True):
        with pytest.raises(ValueError, match="f_number"):
            geometry.camera_equation_factor(n, paraxial=paraxial)
    with pytest.raises(ValueError, match="magnification_"):
        geometry.camera_equation_factor(2.0, math.nan)
    # the values it keeps: pi / (1 + 4 N^2 (1 + |m|)^2) and pi / (4 N^2 (1 + |m|)^2)
    assert float(geometry.camera_equation_factor(2.0, -0.5)) == pytest.approx(math.pi / (1 + 16 * 2.25), rel=1e-14)
    assert float(geometry.camera_equation_factor(2.0, -0.5, paraxial=True)) == pytest.approx(math.pi / 36, rel=1e-14)


def test_relative_illumination_refuses_a_zero_distance_or_f_number():
    with pytest.raises(ValueError, match="image_distance_m"):  # (NaN on the axis)
        geometry.cos4th(X, X, 0.0)
    with pytest.raises(ValueError, match="image_distance_m"):
        geometry.cos4th(X, X, -4e-3)
    with pytest.raises(ValueError, match="f_number"):  # (NaN everywhere)
        geometry.cos4th_isetcam(X, X, 4e-3, 0.0)
    with pytest.raises(ValueError, match="image_distance_m"):
        geometry.cos4th_isetcam(X, X, 0.0, 2.0)
    # cos^4 of the corner angle: (d^2 / (d^2 + r^2))^2
    d, r2 = 4e-3, 2 * 1e-6
    assert float(geometry.cos4th(X, X, d)[0, 0, 0, 0]) == pytest.approx((d**2 / (d**2 + r2)) ** 2, rel=1e-14)


def _psf():
    return torch.ones(1, 1, 5, 5, dtype=torch.float64)


def test_otf_from_psf_refuses_a_psf_without_light_and_a_bad_spacing():
    f = torch.zeros(1, 1, dtype=torch.float64)
    sp = torch.full((1, 1), 1e-6, dtype=torch.float64)
    assert torch.allclose(otf_from_psf(_psf(), sp, f, f).abs(), torch.ones(1, 1, 1, 1, dtype=torch.float64))
    with pytest.raises(ValueError, match="psf"):  # (an OTF of NaN)
        otf_from_psf(torch.zeros(1, 1, 5, 5, dtype=torch.float64), sp, f, f)
    with pytest.raises(ValueError, match="psf"):
        otf_from_psf(torch.full((1, 1, 5, 5), math.nan, dtype=torch.float64), sp, f, f)
    for bad in (-1e-6, 0.0, math.nan):  # (-1e-6: an OTF of 0 at DC, a black image)
        with pytest.raises(ValueError, match="spacing_m"):
            otf_from_psf(_psf(), torch.full((1, 1), bad, dtype=torch.float64), f, f)


def test_analysis_refuses_nan_frequencies_and_a_psf_without_light():
    optics = DiffractionLimitedOptics(2.0, 4e-3)
    with pytest.raises(ValueError, match="frequencies_cpm"):
        analysis.mtf(optics, [550.0], [1e5, math.nan])
    with pytest.raises(ValueError, match="psf_img"):
        analysis.encircled_energy(torch.zeros(9, 9, dtype=torch.float64), 1e-6, [1e-6])
    # wavelengths in micrometres or metres are refused: 0.55 had given the f/4 MTF at 100 c/mm as 0.9997, not the
    # analytic 2 / pi (acos v - v sqrt(1 - v^2)) = 0.722 at v = 100 / (1 / (550e-6 mm x 4))
    f4 = DiffractionLimitedOptics(4.0, 4e-3)
    v = 1e5 * 550e-9 * 4.0
    assert float(analysis.mtf(f4, [550.0], [1e5]).reshape(-1)[0]) == pytest.approx(
        2 / math.pi * (math.acos(v) - v * math.sqrt(1 - v * v)), abs=1e-6)
    for wrong in ([0.55], [5.5e-7]):
        with pytest.raises(ValueError, match=r"^wavelengths_nm: expected wavelengths in nm"):
            analysis.mtf(f4, wrong, [1e5])
        with pytest.raises(ValueError, match=r"^wavelengths_nm: expected wavelengths in nm"):
            analysis.psf(f4, wrong, 1e-6, 16)


def test_plot_psf_extent_centres_the_samples():
    # sample k of psf() sits at (k - size // 2) dx; an image cell spans half a sample either side of it
    pytest.importorskip("matplotlib")
    optics = DiffractionLimitedOptics(2.0, 4e-3)
    for size in (8, 9):
        fig = analysis.plot_psf(optics, 550.0, spacing_m=1e-6, size=size)
        left, right, bottom, top = fig.axes[0].images[0].get_extent()
        assert (left, right) == pytest.approx(((-(size // 2) - 0.5), (size - size // 2 - 0.5)), abs=1e-9)
        assert (top, bottom) == pytest.approx((left, right), abs=1e-9)
        assert (right - left) / size == pytest.approx(1.0)  # one micrometre a cell


def test_isetcam_pad_mode_refuses_options_it_would_ignore():
    for kw, name in (({"camera_equation": "paraxial"}, "camera_equation"), ({"margin": 40}, "margin"),
                     ({"psf_tolerance": 1e-2}, "psf_tolerance"), ({"max_margin_factor": 3.0}, "max_margin_factor")):
        with pytest.raises(ValueError, match=name):
            DiffractionLimitedOptics(2.0, 4e-3, pad_mode="isetcam", **kw)
    DiffractionLimitedOptics(2.0, 4e-3, pad_mode="isetcam", camera_equation="isetcam")  # its own equation


def test_optics_options_name_themselves():
    with pytest.raises(ValueError, match="pupil_diameter_m"):  # (NaN was reported as an f_number error)
        WavefrontOptics(pupil_diameter_m=math.nan, focal_length_m=4e-3)
    with pytest.raises(ValueError, match="psf_tolerance"):  # (a bare TypeError)
        DiffractionLimitedOptics(2.0, 4e-3, psf_tolerance="0.001")
    # a one-value tensor spacing is a spacing, as in the analysis functions
    optics = WavefrontOptics(f_number=2.0, focal_length_m=4e-3)
    layer = torch.zeros(1, 16, 16, dtype=torch.float64)
    layer[0, 8, 8] = 1.0
    a = optics.defocus_maps(layer, torch.tensor(0.5e-6, dtype=torch.float64), 1.0, psf_size=9)
    b = optics.defocus_maps(layer, 0.5e-6, 1.0, psf_size=9)
    assert torch.equal(a, b)
