"""ISET's microlens / pixel-stack model (isettorch.sensor.microlens) against closed forms, an independent NumPy
re-implementation of ISETCam's mlRadiance grid, and in the camera (uniform-field fall-off, gradients)."""

import math

import numpy as np
import pytest
import torch
from finite_difference import central_difference
from scipy import integrate

from isettorch.optics.optical_image import OpticalImage
from isettorch.sensor import CFA, Sensor, SpectralQE
from isettorch.sensor.microlens import (
    ISETCAM_PIXEL,
    PixelOptics,
    microlens_array_offsets_m,
    microlens_etendue,
    microlens_optimal_offset_m,
    microlens_radiance,
)
from isettorch.sensor.pixel_optics import pixel_vignetting

P_UM, D_UM = 2.8, math.sqrt(2.8 ** 2 * 0.75)  # ISETCam default pixel and photodiode (pixelCreate)
LAYERS = ((2.0, 2.0), (5.0, 1.46))  # (thickness um, index): pixelCreate's stack between air and silicon
NA = math.sin(math.atan(1 / 8))  # f/4 source, mlRadiance's sourceNA


def walk_um(p):
    """Lateral walk of a ray of direction sine p (in air) through ISETCam's default stack (Snell per layer)."""
    return sum(t * np.tan(np.arcsin(p / n)) for t, n in LAYERS)


def bare_pixel_closed_form(cra_deg, p_um=P_UM, d_um=D_UM):
    """No microlens (1-D phase space): a ray of direction p entering anywhere on the pixel's width lands shifted by
    walk(p); the photodiode collects overlap([-P/2, P/2] - walk, [-d/2, d/2]) / P; averaged over p uniform in
    sin(CRA) +- NA (Catrysse & Wandell 2002; ISETCam mlRadiance with mlFlag 0)."""
    s = math.sin(math.radians(cra_deg))

    def frac(p):
        w = walk_um(p)
        return max(0.0, min(p_um / 2 - w, d_um / 2) - max(-p_um / 2 - w, -d_um / 2)) / p_um

    val, _ = integrate.quad(frac, s - NA, s + NA, limit=200, epsabs=1e-12)
    return val / (2 * NA)


# --- an independent NumPy copy of ISETCam's mlRadiance grid (mlCoordinates / mlSource / mlLens / mlDisplacement /
# mlPropagate, each re-binned with ffndgrid's nearest-cell mean), written for this test from the MATLAB source
def _ffndgrid_mean(xn, un, w, x, u):
    n = len(x)
    mround = lambda v: np.sign(v) * np.floor(np.abs(v) + 0.5)  # noqa: E731 (MATLAB round)
    bx = mround((xn - x[0]) / (x[1] - x[0]))
    bu = mround((un - u[0]) / (u[1] - u[0]))
    ok = (bx >= 0) & (bx < n) & (bu >= 0) & (bu < n)
    s, c = np.zeros((n, n)), np.zeros((n, n))
    np.add.at(s, (bu[ok].astype(int), bx[ok].astype(int)), w[ok])
    np.add.at(c, (bu[ok].astype(int), bx[ok].astype(int)), 1)
    return np.divide(s, c, out=np.zeros_like(s), where=s != 0)


def isetcam_numpy(cra_deg, microlens=True, offset_um=0.0):
    x = np.linspace(-2 * P_UM, 2 * P_UM, 255)
    u = np.linspace(-0.99, 0.99, 255)
    X, U = np.meshgrid(x, u)
    s = math.sin(math.radians(cra_deg))
    src = ((U > s - NA) & (U < s + NA) & (np.abs(X) < P_UM / 2)).astype(float)
    w = src
    if microlens:
        w = _ffndgrid_mean(X.ravel(), (U + np.sin(np.arctan(X / (7.0 / 1.52)))).ravel(), w.ravel(), x, u)
        w = _ffndgrid_mean((X + offset_um).ravel(), U.ravel(), w.ravel(), x, u)
    for t, n in LAYERS:
        w = _ffndgrid_mean((X - t * np.tan(np.arcsin(U / n))).ravel(), U.ravel(), w.ravel(), x, u)
    return w.sum(0)[np.abs(x) < D_UM / 2].sum() / src.sum(0)[np.abs(x) < P_UM / 2].sum()


ANGLES = (0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0)


def test_defaults_are_isetcams_default_pixel_and_microlens():
    assert ISETCAM_PIXEL["pixel_size_m"] == 2.8e-6
    assert ISETCAM_PIXEL["photodiode_size_m"] == pytest.approx(2.42487e-6, abs=1e-11)
    assert sum(ISETCAM_PIXEL["layer_thicknesses_m"]) == pytest.approx(7e-6)
    assert ISETCAM_PIXEL["microlens_focal_length_m"] / ISETCAM_PIXEL["microlens_f_number"] == pytest.approx(2.8e-6)
    assert (ISETCAM_PIXEL["source_f_number"], ISETCAM_PIXEL["wavelength_nm"]) == (4.0, 500.0)


def test_no_microlens_matches_the_closed_form():
    # the continuous sampling is the exact integral of the model (ISETCam's grid gives 0.83103 on axis)
    got = microlens_etendue(torch.tensor(ANGLES), "none", sampling="continuous")
    want = [bare_pixel_closed_form(a) for a in ANGLES]
    assert got.tolist() == pytest.approx(want, abs=2e-5)
    assert float(got[0]) == pytest.approx(0.82341, abs=1e-4)


def test_a_vanishing_stack_gives_the_1d_fill_factor():
    # no height: every ray lands where it entered; the photodiode takes its share of the width, d / P (the 7 um
    # microlens given: by default its focal length would follow the vanishing stack)
    for method in ("none", "centred"):
        e = microlens_etendue(0.0, method, stack_height_m=1e-12, microlens_focal_length_m=7e-6,
                              sampling="continuous")
        assert float(e) == pytest.approx(D_UM / P_UM, abs=1e-4)


@pytest.mark.parametrize("method", ["none", "centred", "optimal"])
def test_isetcam_grid_equals_an_independent_numpy_copy(method):
    got = microlens_etendue(torch.tensor(ANGLES), method, sampling="isetcam")
    off = [float(walk_um(math.sin(math.radians(a)))) for a in ANGLES]
    want = [isetcam_numpy(a, method != "none", off[i] if method == "optimal" else 0.0) for i, a in enumerate(ANGLES)]
    assert got.tolist() == pytest.approx(want, abs=1e-12)


# ISETCam's numbers: mlRadiance / mlAnalyzeArrayEtendue (with mlCoordinates, mlSource, mlLens, mlDisplacement,
# mlPropagate, ffndgrid, mlensGet('optimal offset'), mlensCreate(sensor) / mlImportParams) at ISET/isetcam commit
# 3aaefc8, computed by an independent NumPy port of that MATLAB source (tests/isetcam_mlradiance.py, which
# test_isetcam_tables_are_the_ports_numbers re-runs), rounded to 6 decimals. Chief-ray angles 0, 5, ..., 30 deg.
ISETCAM_PORT_CRA_DEG = (0.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0)
ISETCAM_PORT = {
    # ISETCam's default pixel (2.8 um, 7 um stack, microlens f = 7 um at f/2.5), source f/4 and f/8
    "default, f/4": ({"source_f_number": 4.0}, {
        "none": [0.831029, 0.775298, 0.654762, 0.512897, 0.380952, 0.230159, 0.110119],
        "centred": [1.0, 1.0, 0.858631, 0.514881, 0.202381, 0.0, 0.0],
        "optimal": [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.998512]}),
    "default, f/8": ({"source_f_number": 8.0}, {
        "none": [0.865546, 0.793651, 0.654762, 0.513889, 0.383929, 0.232143, 0.090278],
        "centred": [1.0, 1.0, 1.0, 0.529762, 0.0, 0.0, 0.0],
        "optimal": [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0]}),
    # a 1.4 um pixel under the default stack, microlens and photodiode following the pixel (mlensCreate(sensor):
    # f = 7 um, D = 1.4 um; photodiode sqrt(0.75) x 1.4 um), source f/4
    "1.4 um pixel": ({"pixel_size_m": 1.4e-6}, {
        "none": [0.738863, 0.628472, 0.373016, 0.15377, 0.037202, 0.0, 0.0],
        "centred": [1.0, 0.68502, 0.34127, 0.003472, 0.0, 0.0, 0.0],
        "optimal": [1.0, 1.0, 1.0, 0.99256, 0.980655, 0.947421, 0.784226]}),
    # the default layers scaled to a 12 um stack (12 * 2/7 um at n = 2.0, 12 * 5/7 um at n = 1.46), microlens
    # f = 12 um (the pixel depth), D = 2.8 um; source f/4
    "12 um stack": ({"stack_height_m": 12e-6}, {
        "none": [0.766513, 0.672123, 0.453373, 0.22619, 0.083829, 0.006944, 0.0],
        "centred": [1.0, 0.774306, 0.430556, 0.086806, 0.0, 0.0, 0.0],
        "optimal": [1.0, 1.0, 1.0, 1.0, 0.998512, 0.984623, 0.960317]}),
}
# where ISETCam's +-2 D phase-space window clips the beam (the 1.4 um pixel's optimal offset, 2.3 um at 30 deg, pushes
# the source past x = 2.8 um): ISETCam drops those rays, the continuous integral keeps them (0.921 vs 0.784)
WINDOW_CLIPPED = {("1.4 um pixel", "optimal", 30.0)}


def test_isetcam_tables_are_the_ports_numbers():
    """The ISETCam tables of this file (ISETCAM_PORT, FALL_OFF_12X16_F30UM, ISETCAM_MAP_4X6_F14UM) are what the
    NumPy port of mlRadiance / mlAnalyzeArrayEtendue gives, to their 6-decimal rounding: re-derivable here."""
    from isetcam_mlradiance import analyze_array_etendue, ml_etendue

    port_method = {"none": "none", "centred": "centered", "optimal": "optimal"}
    port_kw = {"default, f/4": {"source_fnumber": 4.0}, "default, f/8": {"source_fnumber": 8.0},
               "1.4 um pixel": {"pixel_um": 1.4, "pd_um": math.sqrt(0.75) * 1.4, "ml_focal_um": 7.0,
                                "ml_fnumber": 5.0},
               "12 um stack": {"d_stack": (12 * 2 / 7, 12 * 5 / 7), "ml_focal_um": 12.0, "ml_fnumber": 12 / 2.8}}
    assert set(port_kw) == set(ISETCAM_PORT)
    for case, (_, table) in ISETCAM_PORT.items():
        for method, want in table.items():
            got = [ml_etendue(a, port_method[method], **port_kw[case]) for a in ISETCAM_PORT_CRA_DEG]
            np.testing.assert_allclose(got, want, rtol=0, atol=5e-7, err_msg=f"{case}, {method}")
    for method in ("none", "centred", "optimal"):
        _, cra, etendue, _ = analyze_array_etendue(12, 16, 2.8, 30.0, port_method[method])
        np.testing.assert_allclose(cra, FALL_OFF_12X16_F30UM["cra_deg"], rtol=0, atol=5e-7)
        np.testing.assert_allclose(etendue, FALL_OFF_12X16_F30UM[method], rtol=0, atol=5e-7)
        emap = analyze_array_etendue(4, 6, 2.8, 14.0, port_method[method])[0]
        np.testing.assert_allclose(emap[2:, 3:], ISETCAM_MAP_4X6_F14UM[method], rtol=0, atol=5e-7)


@pytest.mark.parametrize("case", sorted(ISETCAM_PORT))
@pytest.mark.parametrize("method", ["none", "centred", "optimal"])
def test_etendue_equals_isetcams_numbers(case, method):
    pixel, table = ISETCAM_PORT[case]
    cra = torch.tensor(ISETCAM_PORT_CRA_DEG, dtype=torch.float64)
    want = table[method]
    # the default sampling is ISETCam's grid: its numbers (to the table's rounding)
    assert microlens_etendue(cra, method, **pixel).tolist() == pytest.approx(want, abs=1e-5)
    assert microlens_etendue(cra, method, sampling="isetcam", **pixel).tolist() == pytest.approx(want, abs=1e-5)
    # the continuous integral of the same model: within 0.02 (measured <= 0.0164 on these cases; 0.030 at worst on
    # the default pixel, f/8, 13.5 deg), except where ISETCam's window clips the beam
    cont = microlens_etendue(cra, method, sampling="continuous", **pixel).tolist()
    for a, got, ref in zip(ISETCAM_PORT_CRA_DEG, cont, want):
        if (case, method, a) in WINDOW_CLIPPED:
            assert got > ref + 0.1
        else:
            assert got == pytest.approx(ref, abs=0.02), a


def test_defaults_follow_the_pixel():
    """mlensCreate(sensor) / mlImportParams: microlens focal length = pixel depth, diameter = pixel width; the
    photodiode is pixelCreate's 75 % fill. The explicit values give the same numbers; the default pixel is
    ISETCAM_PIXEL."""
    cra = torch.tensor([0.0, 10.0, 20.0], dtype=torch.float64)
    for method in ("none", "centred", "optimal"):
        implicit = microlens_etendue(cra, method, pixel_size_m=1.4e-6, stack_height_m=5e-6)
        explicit = microlens_etendue(cra, method, pixel_size_m=1.4e-6, stack_height_m=5e-6,
                                     microlens_focal_length_m=5e-6, microlens_diameter_m=1.4e-6,
                                     photodiode_size_m=math.sqrt(0.75) * 1.4e-6)
        assert torch.equal(implicit, explicit)
        isetcam_pixel = {k: ISETCAM_PIXEL[k] for k in ("pixel_size_m", "photodiode_size_m", "microlens_focal_length_m",
                                                       "microlens_f_number", "source_f_number")}
        assert torch.equal(microlens_etendue(cra, method), microlens_etendue(cra, method, **isetcam_pixel))


def test_isetcam_published_behaviour_of_the_default_pixel():
    """ISETCam's default pixel (v_microlens / mlAnalyzeArrayEtendue): at 0 deg a centred microlens collects all the
    light, the bare pixel ~0.83; the bare pixel falls off with CRA, the centred microlens falls to 0 by 25 deg, the
    optimal offset keeps ~1 to 30 deg. The continuous integral agrees with ISETCam's grid (the default sampling) to
    0.016 here (its grid's bias)."""
    cra = torch.arange(0.0, 35.01, 2.5)
    grid = {m: microlens_etendue(cra, m) for m in ("none", "centred", "optimal")}
    for method, g in grid.items():
        assert torch.equal(g, microlens_etendue(cra, method, sampling="isetcam"))
        assert float((g - microlens_etendue(cra, method, sampling="continuous")).abs().max()) < 0.016, method
    at = {a: i for i, a in enumerate(cra.tolist())}
    assert float(grid["none"][0]) == pytest.approx(0.831, abs=1e-3)
    assert grid["centred"][:3].tolist() == [1.0, 1.0, 1.0] and float(grid["centred"][at[25.0]:].abs().max()) == 0.0
    assert bool((grid["none"].diff() < 0).all()) and bool((grid["centred"].diff() <= 0).all())
    assert float(grid["optimal"][: at[30.0] + 1].min()) > 0.995
    # a centred microlens beats the bare pixel on axis and loses to it at large angles (the 2002 paper's point)
    assert float(grid["centred"][at[10.0]]) > float(grid["none"][at[10.0]])
    assert bool((grid["centred"][at[20.0]:] < grid["none"][at[20.0]:]).all())


def test_optimal_offset_is_the_chief_rays_walk():
    cra = torch.tensor([0.0, 10.0, 20.0, 30.0])
    got = microlens_optimal_offset_m(cra)
    want = [walk_um(math.sin(math.radians(a))) * 1e-6 for a in cra.tolist()]
    assert got.tolist() == pytest.approx(want, rel=1e-12, abs=1e-18)
    # a single homogeneous layer: h tan(asin(sin(theta) / n))
    one = microlens_optimal_offset_m(20.0, stack_height_m=7e-6, stack_index=1.5)
    assert float(one) == pytest.approx(7e-6 * math.tan(math.asin(math.sin(math.radians(20)) / 1.5)), rel=1e-12)
    # mlOptimalOffsets: f_ml tan(asin(sin(atan(r / f_source)) / 1.5)) at a pixel of a 3 x 5 array
    arr = microlens_array_offsets_m(3, 5, 1e-3)
    r = math.hypot(1e-3, 2e-3)
    assert float(arr[0, 0]) == pytest.approx(7e-6 * math.tan(math.asin(math.sin(math.atan(r / 3.862755099e-3)) / 1.5)))
    assert float(arr[1, 2]) == 0.0


@pytest.mark.parametrize("sampling", ["isetcam", "continuous"])
def test_radiance_outputs_and_irradiance_shape(sampling):
    r = microlens_radiance(torch.tensor([0.0, 20.0]), "centred", sampling=sampling)
    irr = r["irradiance"]
    assert irr.shape == (2, 255, 255) and float(irr.amax()) == pytest.approx(1.0)
    assert torch.allclose(irr, irr.transpose(-1, -2))  # separable x-y outer product
    x = r["x_m"]
    # on axis the focused spot sits inside the photodiode; at 20 deg the centred microlens's spot walks off it
    prof = irr.sum(-2)
    centroid = (prof * x).sum(-1) / prof.sum(-1)
    assert abs(float(centroid[0])) < 0.05e-6 and float(centroid[1]) < -D_UM / 2 * 1e-6
    g = microlens_radiance(torch.tensor([10.0]), "none", sampling="isetcam")
    assert g["irradiance"].shape == (1, 255, 255)


def test_diffraction_depends_on_wavelength():
    wl = torch.tensor([400.0, 550.0, 700.0])
    e = microlens_etendue(0.0, "centred", sampling="continuous", diffraction=True, wavelength_nm=wl)
    assert bool((e.diff() < 0).all())  # longer wavelengths spread more and lose more
    # a small pixel loses more to diffraction than a large one with the same stack (1.4 vs 2.8 um)
    small = microlens_etendue(0.0, "centred", sampling="continuous", diffraction=True, wavelength_nm=700.0,
                              pixel_size_m=1.4e-6)
    assert float(small) < float(e[-1]) - 0.1
    # a vanishing wavelength is the ray model
    ray = microlens_etendue(torch.tensor([0.0, 12.0]), "centred", sampling="continuous")
    tiny = microlens_etendue(torch.tensor([0.0, 12.0]), "centred", sampling="continuous", diffraction=True,
                             wavelength_nm=1e-3)
    assert tiny.tolist() == pytest.approx(ray.tolist(), abs=2e-3)
    with pytest.raises(ValueError, match="sampling='continuous'"):  # ISETCam's grid has no diffraction
        microlens_etendue(0.0, "centred", diffraction=True)


def test_gradients_to_stack_height_and_offset():
    h = torch.tensor(7.0, dtype=torch.float64, requires_grad=True)  # um
    o = torch.tensor(0.3, dtype=torch.float64, requires_grad=True)  # um

    def f(h_um, o_um):
        return microlens_etendue(torch.tensor([8.0, 14.0]), "centred", sampling="continuous", diffraction=True,
                                 stack_height_m=h_um * 1e-6, offset_m=o_um * 1e-6, samples=(48, 96))

    assert torch.autograd.gradcheck(f, (h, o), eps=1e-4, atol=1e-4, rtol=1e-3)
    # the hard-edged ray model is differentiable too: autograd against central differences (the microlens focal
    # length follows the stack height by default, as ISETCam's mlensCreate(sensor) builds it)
    e = microlens_etendue(15.0, "centred", sampling="continuous", stack_height_m=h * 1e-6, offset_m=o * 1e-6)
    gh, go = torch.autograd.grad(e, (h, o))
    with torch.no_grad():
        def fd(dh, do):
            return float(microlens_etendue(15.0, "centred", sampling="continuous",
                                           stack_height_m=(7.0 + dh) * 1e-6, offset_m=(0.3 + do) * 1e-6))
        assert float(gh) == pytest.approx((fd(1e-3, 0) - fd(-1e-3, 0)) / 2e-3, rel=0.02)
        assert float(go) == pytest.approx((fd(0, 1e-3) - fd(0, -1e-3)) / 2e-3, rel=0.02)
    assert float(gh) < 0 < float(go)  # a taller stack loses the oblique beam; an offset towards it recovers it
    # ISETCam's grid has no gradients: refused, not silently detached
    with pytest.raises(ValueError, match="sampling='continuous'"):
        microlens_etendue(15.0, "centred", stack_height_m=h * 1e-6)


def test_isetcam_names_are_accepted():
    base = microlens_etendue(torch.tensor([5.0, 12.0]), "centred", offset_m=0.2e-6)
    same = microlens_etendue(torch.tensor([5.0, 12.0]), "centred", microlens_offset_m=0.2e-6, pixel_width_m=2.8e-6,
                             photodiode_width_m=D_UM * 1e-6, source_focal_length_m=5e-3, microlens_index=1.5)
    assert torch.allclose(base, same, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="given twice"):
        microlens_etendue(0.0, pixel_width_m=2.8e-6, pixel_size_m=2.8e-6)


def test_geometric_model_option():
    e = microlens_etendue(torch.tensor([0.0, 15.0]), "none", model="geometric")
    n_eq = 7.0 / (2.0 / 2.0 + 5.0 / 1.46)
    want = pixel_vignetting(torch.tensor([0.0, 15.0]), 4.0, 7e-6, 2.8e-6, D_UM * 1e-6, stack_index=n_eq,
                            microlens=False)
    assert e.tolist() == pytest.approx(want.tolist(), abs=1e-12)
    assert float(microlens_etendue(0.0, "centred", model="geometric")) == pytest.approx(1.0)


def test_errors_name_the_argument():
    with pytest.raises(ValueError, match="method"):
        microlens_etendue(0.0, "sideways")
    with pytest.raises(ValueError, match="stack_index"):
        microlens_etendue(0.0, stack_index=0.8)
    with pytest.raises(ValueError, match="photodiode_size_m"):
        microlens_etendue(0.0, photodiode_size_m=3e-6)
    with pytest.raises(ValueError, match="chief_ray_angle_deg"):
        microlens_etendue(torch.tensor([95.0]))
    with pytest.raises(ValueError, match="not a microlens"):
        microlens_etendue(0.0, pixel_width=3e-6)
    with pytest.raises(ValueError, match="offset_m"):
        microlens_etendue(0.0, "none", offset_m=1e-7)
    with pytest.raises(ValueError, match="microlens_diameter_m"):
        microlens_etendue(0.0, microlens_diameter_m=3e-6)
    # explicit values win over the defaults that follow the pixel, and one wider than the pixel is refused
    with pytest.raises(ValueError, match=r"microlens_f_number: .* wider than the pixel .* microlens_f_number >= 5"):
        microlens_etendue(0.0, pixel_size_m=1.4e-6, microlens_f_number=2.5)
    with pytest.raises(ValueError, match=r"photodiode_size_m: .* wider than the pixel .* omit it"):
        microlens_etendue(0.0, pixel_size_m=1.4e-6, photodiode_size_m=2.42e-6)
    with pytest.raises(ValueError, match="grid_points"):
        microlens_radiance(0.0, grid_points=0)
    with pytest.raises(ValueError, match="convention: 'isetcam'.*learnable"):
        PixelOptics("centred", convention="isetcam", learnable=True)
    with pytest.raises(ValueError, match="convention: 'isetcam'.*diffraction"):
        PixelOptics("centred", convention="isetcam", diffraction=True)
    with pytest.raises(ValueError, match="unknown key 'stack'"):
        Sensor(pixel_optics={"stack": 1})
    # what gave NaN or a silent 0 (hard-case audit): a source cone between ISETCam's grid rows (f/200: etendue 0 / 0),
    # non-finite layers and offsets, a microlens index below 1
    with pytest.raises(ValueError, match=r"source_f_number: .*ISETCam's 255-point direction grid.*continuous"):
        microlens_etendue(torch.arange(0.0, 31.0, 0.5), "centred", source_f_number=200.0, sampling="isetcam")
    with pytest.raises(ValueError, match=r"chief_ray_angle_deg: the source's cone .* lies beyond ISETCam's direction"):
        microlens_etendue(torch.tensor([88.0]), "centred", source_f_number=100.0, sampling="isetcam")
    cont = microlens_etendue(torch.arange(0.0, 31.0, 0.5), "centred", source_f_number=200.0, sampling="continuous")
    assert bool(torch.isfinite(cont).all()) and float(cont.min()) >= 0 and float(cont.max()) <= 1
    with pytest.raises(ValueError, match="layer_thicknesses_m: expected positive finite"):
        microlens_etendue(0.0, layer_thicknesses_m=(math.nan, 5e-6))
    with pytest.raises(ValueError, match="layer_indices/stack_index: expected refractive indices >= 1"):
        microlens_etendue(0.0, layer_indices=(math.nan, 1.46))
    with pytest.raises(ValueError, match="offset_m: expected finite offsets"):
        microlens_etendue(0.0, "centred", offset_m=math.inf)
    with pytest.raises(ValueError, match="method: expected one of"):
        microlens_etendue(0.0, None)  # (was read as 'none')
    with pytest.raises(ValueError, match=r"source_f_number: expected one value .* got shape \(2,\)"):
        microlens_etendue(0.0, source_f_number=torch.tensor([2.0, 4.0]))
    with pytest.raises(ValueError, match="microlens_index: expected a refractive index >= 1"):
        microlens_array_offsets_m(4, 4, 2.8e-6, microlens_index=0.5)
    with pytest.raises(TypeError, match="pixel_optics"):
        Sensor(pixel_optics=3)


# --- in the sensor and the camera ------------------------------------------------------------------------------

def _uniform_oi(rows, cols, pitch, d_m, f_number=4.0, waves=None):
    waves = torch.arange(400.0, 701.0, 50.0) if waves is None else waves
    return OpticalImage(torch.full((1, len(waves), rows, cols), 1e15, dtype=torch.float64), waves,
                        sample_spacing_m=torch.tensor([pitch], dtype=torch.float64),
                        focal_length_m=torch.tensor([d_m]), image_distance_m=torch.tensor([d_m]),
                        f_number=torch.tensor([f_number]))


# ISETCam mlAnalyzeArrayEtendue (sensorVignetting) on ISETCam's default pixel, 12 x 16 pixels of 2.8 um, source f/4
# with focal length 30 um: the etendue at cra = (0:5) / 5 * max(sensorCRA(:)); from the port of mlRadiance
# (tests/isetcam_mlradiance.py)
FALL_OFF_12X16_F30UM = {
    "cra_deg": [0.0, 8.191924, 16.383848, 24.575772, 32.767696, 40.95962],
    "none": [0.831029, 0.703869, 0.474206, 0.244544, 0.065972, 0.000496],
    "centred": [1.0, 0.980655, 0.421131, 0.0, 0.0, 0.0],
    "optimal": [1.0, 1.0, 1.0, 1.0, 0.993552, 0.956845],
}


@pytest.mark.parametrize("method", ["none", "centred", "optimal"])
def test_sensor_fall_off_on_a_uniform_field(method):
    rows, cols, pitch = 12, 16, 2.8e-6
    d = 30e-6  # a short focal length so the 16 x 12 pixels span 0 to 41 deg
    oi = _uniform_oi(rows, cols, pitch, d)
    kw = dict(rows=rows, cols=cols, read_noise_v=0.0, dark_current_e_per_s=0.0)
    plain = Sensor.preset("isetcam_default", **kw).electron_rate(oi)
    iset = Sensor.preset("isetcam_default", pixel_optics={"method": method, "convention": "isetcam"},
                         **kw).electron_rate(oi)
    phys = Sensor.preset("isetcam_default", pixel_optics={"method": method, "angle_samples": 129}, **kw)
    y = (torch.arange(rows, dtype=torch.float64) - (rows - 1) / 2) * pitch
    x = (torch.arange(cols, dtype=torch.float64) - (cols - 1) / 2) * pitch
    cra = torch.rad2deg(torch.atan(torch.hypot(y[:, None], x[None, :]) / d))  # ISETCam sensorGet(sensor, 'cra')
    # ISETCam: volts x interp1(cra samples, etendue, sensorCRA), the fill-factor signal kept
    ref = FALL_OFF_12X16_F30UM
    assert float(cra.max()) == pytest.approx(ref["cra_deg"][-1], abs=1e-5)
    want_iset = np.interp(cra.numpy(), ref["cra_deg"], ref[method])
    assert np.abs((iset[0, 0] / plain[0, 0]).numpy() - want_iset).max() < 1e-5
    # physical convention: the whole pixel's light x the continuous integral's etendue along the pixel's columns and
    # rows, at the chief-ray angles of the image points (x, 0) and (0, y) (fill factor 0.75 undone)
    def along(c):
        return microlens_etendue(torch.rad2deg(torch.atan(c.abs() / d)), method, samples=(64, 128),
                                 sampling="continuous")

    want = along(y)[:, None] * along(x)[None, :]
    assert torch.allclose(phys.electron_rate(oi)[0, 0] / plain[0, 0] * 0.75, want, atol=3e-3)
    assert torch.allclose(phys.pixel_optics.chief_ray_angle_deg(oi, rows, cols, pitch)[0], cra)


# ISETCam mlAnalyzeArrayEtendue on 4 x 6 pixels of ISETCam's default pixel (2.8 um), optics focal length 14 um (CRA
# to 30.25 deg), f/4: the map's lower-right quarter (rows 2-3, columns 3-5; the map is point-symmetric), from the
# port of mlRadiance (tests/isetcam_mlradiance.py)
ISETCAM_MAP_4X6_F14UM = {
    "none": [[0.706264, 0.445459, 0.18929], [0.445459, 0.292285, 0.110119]],
    "centred": [[0.911924, 0.348084, 0.0], [0.348084, 0.061005, 0.0]],
    "optimal": [[1.0, 1.0, 0.999306], [1.0, 1.0, 0.998512]],
}


@pytest.mark.parametrize("method", ["none", "centred", "optimal"])
def test_isetcam_convention_map_is_isetcams(method):
    # the image distance differs from the focal length: ISETCam's sensorGet(sensor, 'cra') uses the focal length
    oi = OpticalImage(torch.ones(1, 1, 4, 6, dtype=torch.float64), torch.tensor([550.0]),
                      sample_spacing_m=torch.tensor([2.8e-6], dtype=torch.float64),
                      focal_length_m=torch.tensor([14e-6], dtype=torch.float64), image_distance_m=torch.tensor([20e-6]),
                      f_number=torch.tensor([4.0]))
    po = PixelOptics(method, convention="isetcam")
    emap = po.etendue_map(oi, 4, 6, 2.8e-6, 0.75)[0]
    assert torch.equal(emap, emap.flip(0, 1))
    assert np.abs(emap[2:, 3:].numpy() - np.array(ISETCAM_MAP_4X6_F14UM[method])).max() < 1e-5
    corner_cra = math.degrees(math.atan(math.hypot(1.5, 2.5) * 2.8 / 14))
    assert float(po.chief_ray_angle_deg(oi, 4, 6, 2.8e-6)[0, 0, 0]) == pytest.approx(corner_cra, rel=1e-12)


def test_camera_with_pixel_optics_and_gradients():
    from isettorch.camera import Camera
    from isettorch.optics import DiffractionLimitedOptics
    from isettorch.scene.patterns import uniform

    optics = DiffractionLimitedOptics(f_number=4.0, focal_length_m=40e-6)  # short: CRAs up to ~38 deg
    kw = dict(rows=16, cols=16, cfa="RGGB", pixel_size_m=2.8e-6, exposure_s=1e-3)
    sensor = Sensor(pixel_optics={"method": "centred", "learnable": True}, **kw)  # physical: differentiable
    # the physical convention takes the whole pixel's light (the window and the area of a bare pixel of fill 1)
    cam, ref = Camera(optics, sensor, noise=False), Camera(optics, Sensor(**kw, fill_factor=1.0), noise=False)
    scene = uniform("D65", size=32, hfov_deg=2 * math.degrees(math.atan(16 * 2.8e-6 / 2 / 40e-6)) * 2,
                    dtype=torch.float64)
    out, base = cam(scene, return_intermediates=True), ref(scene, return_intermediates=True)
    ratio = (out.raw.noise_free / base.raw.noise_free)[0, 0]
    emap = sensor.etendue_map(out.optical_image)[0].detach()
    assert torch.allclose(ratio.detach(), emap.to(ratio), rtol=1e-12, atol=0)
    assert float(emap[8, 8]) > 0.99 and float(emap[0, 0]) < 0.9  # centre vs corner fall-off
    loss = out.raw.noise_free.mean()
    loss.backward()
    po = sensor.pixel_optics
    assert po.log_stack_height_m.grad is not None and float(po.log_stack_height_m.grad) < 0
    assert float(po.stack_height_m.detach()) == pytest.approx(7e-6)
    assert po.offset_per_image_height.grad is not None and float(po.offset_per_image_height.grad) > 0


def test_a_learnable_f_number_gets_the_pixel_optics_share_of_its_gradient():
    """The source f-number sets the cone the microlens takes in, so through pixel optics the raw's gradient in a
    learnable f-number includes the etendue's change: autograd equals a central difference (the f-number was cast to a
    float there, which gave 2.3x the true gradient, the camera equation's share alone)."""
    from isettorch.optics import DiffractionLimitedOptics
    from isettorch.scene.patterns import uniform

    optics = DiffractionLimitedOptics(f_number=2.0, focal_length_m=40e-6, learn_f_number=True)
    sensor = Sensor(rows=12, cols=12, cfa="RGGB", pixel_size_m=2.8e-6, exposure_s=1e-3,
                    pixel_optics={"method": "optimal", "samples": [32, 64]})
    scene = uniform("D65", size=24, hfov_deg=2 * math.degrees(math.atan(12 * 2.8e-6 / 2 / 40e-6)) * 2,
                    dtype=torch.float64)
    weights = torch.rand(1, 1, 12, 12, dtype=torch.float64, generator=torch.Generator().manual_seed(0))

    def loss():
        return (sensor(optics(scene), noise=False).noise_free * weights).sum()

    (grad,) = torch.autograd.grad(loss(), optics.f_number)
    # autograd is the etendue integral's derivative (Leibniz's rule in the span of directions), the difference
    # that of the 32-direction sum, whose terms step as directions cross the span: it moves by up to 0.9 % with the
    # step (2e-4 to 5e-2) while autograd converges (-0.74309 / -0.74296 / -0.74293 at 32 / 64 / 128 directions);
    # they agree to 0.4 % here (the missing share was a factor 2.3)
    assert float(grad) == pytest.approx(central_difference(loss, optics.f_number, 2e-4), rel=1e-2)


def test_a_learnable_f_number_is_refused_where_the_etendue_has_no_gradient():
    """The geometric model and ISETCam's grid have no gradient in the f-number: the etendue's share of d/dN was
    dropped without a word (0.64 % of it through the geometric model). Each is refused; the physical phase-space
    integral (above) differentiates it."""
    from isettorch.optics import DiffractionLimitedOptics
    from isettorch.scene.patterns import uniform

    n = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)
    with pytest.raises(ValueError, match="model: 'geometric'.* has no gradients"):
        microlens_etendue(torch.tensor([30.0]), "none", model="geometric", source_f_number=n, pixel_size_m=20e-6)
    with pytest.raises(ValueError, match="sampling: 'isetcam'.* has no gradients"):
        microlens_etendue(torch.tensor([30.0]), "none", source_f_number=n, pixel_size_m=20e-6)
    optics = DiffractionLimitedOptics(f_number=2.0, focal_length_m=40e-6, learn_f_number=True)
    scene = uniform("D65", size=24, hfov_deg=2 * math.degrees(math.atan(12 * 2.8e-6 / 2 / 40e-6)) * 2,
                    dtype=torch.float64)
    for settings in ({"model": "geometric"}, {"convention": "isetcam"}):
        sensor = Sensor(rows=12, cols=12, cfa="RGGB", pixel_size_m=2.8e-6, exposure_s=1e-3,
                        pixel_optics={"method": "none", **settings})
        with pytest.raises(ValueError, match="pixel_optics: the optics' f-number requires grad"):
            sensor(optics(scene), noise=False)


def test_isetcam_grid_at_a_tie_is_isetcams():
    """Where a source cone's edge falls exactly on a row of ISETCam's direction grid (CRA 45 degrees at f/0.5:
    sin 45 = the cone's edge), the strict comparison of mlSource decides; torch.linspace's grid put that row 1 ulp
    off MATLAB's (and NumPy's) and counted it: 0.0382 against ISETCam's 0.0306."""
    from isetcam_mlradiance import ml_etendue

    for method, port in (("none", "none"), ("centred", "centered")):
        got = microlens_etendue(torch.tensor([45.0]), method, photodiode_size_m=0.28e-6, source_f_number=0.5,
                                microlens_focal_length_m=7e-6, microlens_f_number=2.5)
        want = ml_etendue(45.0, port, source_fnumber=0.5, pd_um=0.28, ml_focal_um=7.0, ml_fnumber=2.5)
        assert float(got) == pytest.approx(want, abs=1e-12)


def test_per_wavelength_etendue_shades_colour():
    rows = cols = 8
    oi = _uniform_oi(rows, cols, 1.4e-6, 40e-6, f_number=2.0, waves=torch.tensor([450.0, 550.0, 650.0]))
    po = {"method": "centred", "diffraction": True, "layer_thicknesses_m": [1e-6, 2e-6],
          "layer_indices": [1.46, 1.6], "microlens_focal_length_m": 3e-6}
    s = Sensor(rows=rows, cols=cols, pixel_size_m=1.4e-6, cfa="RGGB", pixel_optics=po)
    emap = s.etendue_map(oi)
    assert emap.shape == (1, 3, rows, cols)
    assert float(emap[0, 0, 3, 3]) > float(emap[0, 2, 3, 3])  # on axis blue keeps more than red
    # each band's map is the 1-D model at that wavelength along the pixel's columns and rows: the corner pixel's
    # coordinates are both 3.5 pitches, the chief ray of the image point (3.5 pitches, 0) at atan(3.5 x 1.4 / 40)
    cra = math.degrees(math.atan(3.5 * 1.4e-6 / 40e-6))
    kw = dict(diffraction=True, pixel_size_m=1.4e-6, photodiode_size_m=1.4e-6 * math.sqrt(0.75),
              microlens_diameter_m=1.4e-6, layer_thicknesses_m=(1e-6, 2e-6), layer_indices=(1.46, 1.6),
              microlens_focal_length_m=3e-6, source_f_number=2.0, samples=(64, 128), sampling="continuous")
    for i, wl in enumerate((450.0, 550.0, 650.0)):
        want = microlens_etendue(cra, "centred", wavelength_nm=wl, **kw) ** 2
        assert float(emap[0, i, 0, 0]) == pytest.approx(float(want), abs=3e-3)
    rates, _ = s.channel_rates(oi)
    plain, _ = Sensor(rows=rows, cols=cols, pixel_size_m=1.4e-6, cfa="RGGB").channel_rates(oi)
    ratio = rates / plain
    # colour shading: the corner-to-centre fall-off differs between the red and the blue channel
    assert s.cfa.channel_names[0] == "R" and s.cfa.channel_names[-1] == "B"
    r_fall, b_fall = float(ratio[0, 0, 0, 0] / ratio[0, 0, 3, 3]), float(ratio[0, -1, 0, 0] / ratio[0, -1, 3, 3])
    assert abs(r_fall - b_fall) > 0.01


def test_lens_chief_ray_table_drives_the_map():
    pytest.importorskip("isettorch.optics.lens")
    from isettorch.optics.factory import build_optics

    lens = build_optics({"type": "lens", "lens": "cooke_triplet", "field_samples": 3, "components": 2,
                         "distortion_samples": 6, "ri_samples": 16})
    table = lens.chief_ray_angle_table()
    a = lens.analysis
    cra_edge = float(a.chief_ray_angle_deg(1.0, a.reference_wavelength_nm))  # the table is at the primary wavelength
    assert float(table["cra_deg"][-1]) == pytest.approx(cra_edge, abs=1e-9)
    oi = _uniform_oi(4, 4, 1e-3, float(lens.focal_length_m))
    oi.metadata["chief_ray_angle"] = table
    po = PixelOptics("centred")
    r = float(table["image_height_m"][5])
    got = po._cra_of_radius(oi, torch.tensor([r], dtype=torch.float64))
    assert float(got[0, 0]) == pytest.approx(float(table["cra_deg"][5]), abs=1e-9)
    # a sensor beyond the traced field is refused
    with pytest.raises(ValueError, match="beyond the lens"):
        po._cra_of_radius(oi, torch.tensor([1.0], dtype=torch.float64))


def test_config_with_microlenses_builds():
    from isettorch.camera import Camera
    from isettorch.scene.macbeth import macbeth

    for name in ("isetcam_microlens", "phone_microlens"):
        cam = Camera.from_config(name)
        assert isinstance(cam.sensor.pixel_optics, PixelOptics)
        cam.sensor.rows, cam.sensor.cols = 16, 24
        out = cam(macbeth(patch_size=4), return_intermediates=True)
        assert out.image.shape == (1, 3, 16, 24) and torch.isfinite(out.image).all()
        emap = cam.sensor.etendue_map(out.optical_image)
        assert bool((emap > 0).all()) and bool((emap <= 1 + 1e-9).all())
    assert Camera.from_config("phone_microlens").sensor.pixel_optics.wavelength_dependent
    assert Camera.from_config("default").sensor.pixel_optics is None


def test_ray_traced_lens_camera_uses_the_traced_chief_rays():
    pytest.importorskip("opticalglass")
    from isettorch.camera import Camera, load_config
    from isettorch.optics.lens.optics import LensOptics
    from isettorch.scene.scene import Scene

    cfg = load_config("cooke_lens")
    pitch = 0.4e-3  # coarse "pixels" so a small sensor spans the lens's field
    # the pixel model is ISETCam's scaled to that pitch (the ray model has no length scale: the same etendue); the
    # pixel optics' pixel is the sensor's (a different pixel_size_m there is an error), photodiode sqrt(0.75) x pitch
    k = pitch / (P_UM * 1e-6)
    stack = [t * 1e-6 * k for t, _ in LAYERS]
    cfg["sensor"].update(rows=None, cols=None, pixel_size_m=pitch,
                         pixel_optics={"method": "none", "layer_thicknesses_m": stack, "angle_samples": 65})
    cam = Camera.from_config(cfg)
    cam.optics = LensOptics(cam.optics.analysis, field_samples=3, azimuth_samples=4, components=4,
                            distortion_samples=6, ri_samples=24)
    scene = Scene(torch.full((1, 3, 24, 24), 1e16, dtype=torch.float64), torch.tensor([450.0, 550.0, 650.0]),
                  hfov_deg=20.0)
    out = cam(scene, return_intermediates=True)
    oi = out.optical_image
    table = oi.metadata["chief_ray_angle"]
    rows, cols = out.raw.data.shape[-2:]
    cra = cam.sensor.pixel_optics.chief_ray_angle_deg(oi, rows, cols, pitch)[0]
    r_corner = math.hypot((rows - 1) / 2, (cols - 1) / 2) * pitch
    want_cra = float(np.interp(r_corner, table["image_height_m"].numpy(), table["cra_deg"].numpy()))
    assert float(cra[0, 0]) == pytest.approx(want_cra, abs=1e-9)
    thin = math.degrees(math.atan(r_corner / float(cam.optics.focal_length_m)))
    assert abs(want_cra - thin) > 0.05  # the traced angle, not the thin lens's
    emap = cam.sensor.etendue_map(oi)[0]
    # the map is separable along the pixel's columns and rows: the corner pixel's etendue is the 1-D one at the
    # traced chief rays of the image points (x, 0) and (0, y)
    cra_xy = np.interp([(cols - 1) / 2 * pitch, (rows - 1) / 2 * pitch], table["image_height_m"].numpy(),
                       table["cra_deg"].numpy())
    e = microlens_etendue(torch.tensor(cra_xy), "none", source_f_number=float(oi.f_number[0]),
                          samples=(64, 128), pixel_size_m=pitch, photodiode_size_m=D_UM * 1e-6 * k,
                          layer_thicknesses_m=stack, microlens_diameter_m=pitch, sampling="continuous")
    assert float(emap[0, 0]) == pytest.approx(float(e[0] * e[1]), abs=2e-3)
    # the same etendue as ISETCam's own 2.8 um pixel at these angles (scale-free rays)
    e_isetcam = microlens_etendue(torch.tensor(cra_xy), "none", source_f_number=float(oi.f_number[0]),
                                  samples=(64, 128), sampling="continuous")
    assert float(e[0] * e[1]) == pytest.approx(float(e_isetcam[0] * e_isetcam[1]), abs=1e-9)
    assert float(e[0]) < 0.99  # the traced angle vignettes: the check is not trivial


def test_f_number_and_angle_gradients_follow_the_integral():
    """d(etendue)/d(f-number) and d/d(CRA) of the continuous integral are those of the integral: against central
    differences of a 4096-direction evaluation (the midpoint sum's own gradient, which the focused beam's near-step
    makes noisy, read 0.247 for 0.154 at 64 directions and 0.196 at 512)."""
    cra = torch.tensor([3.0, 12.0, 22.0], dtype=torch.float64)

    def e(n_f, c, samples):
        return microlens_etendue(c, "centred", sampling="continuous", samples=samples, source_f_number=n_f).sum()

    n = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)
    c = cra.clone().requires_grad_(True)
    g_n, g_c = torch.autograd.grad(e(n, c, (64, 128)), (n, c))
    with torch.no_grad():
        fine = (4096, 128)
        fd_n = (e(2.05, cra, fine) - e(1.95, cra, fine)) / 0.1
        fd_c = [(e(2.0, cra + 0.2 * d, fine) - e(2.0, cra - 0.2 * d, fine)) / 0.4 for d in torch.eye(3)]
    assert float(g_n) == pytest.approx(float(fd_n), abs=0.006)
    assert float(fd_n) == pytest.approx(0.154, abs=0.003)  # the audit's independent 3000 x 3000 integral
    for k in range(3):
        assert float(g_c[k]) == pytest.approx(float(fd_c[k]), abs=0.006)
    # 'optimal': the offset follows the CRA, so the CRA's share moves the samples (Leibniz's rule alone gave -0.061
    # for -0.0056 at 22 deg, f/2.8, a 1.4 um pixel); the f-number's is Leibniz's rule
    for diffraction, tol in ((False, 0.004), (True, 2e-4)):
        kw = dict(sampling="continuous", pixel_size_m=1.4e-6, diffraction=diffraction)
        n = torch.tensor(2.8, dtype=torch.float64, requires_grad=True)
        c = torch.tensor([22.0], dtype=torch.float64, requires_grad=True)
        g_n, g_c = torch.autograd.grad(microlens_etendue(c, "optimal", source_f_number=n, samples=(64, 128),
                                                         **kw).sum(), (n, c))
        with torch.no_grad():
            def fine(nf, cd, kw=kw):
                return float(microlens_etendue(torch.tensor([cd], dtype=torch.float64), "optimal",
                                               source_f_number=nf, samples=(4096, 256), **kw).sum())
            assert float(g_c[0]) == pytest.approx((fine(2.8, 22.25) - fine(2.8, 21.75)) / 0.5, abs=tol)
            assert float(g_n) == pytest.approx((fine(2.85, 22.0) - fine(2.75, 22.0)) / 0.1, abs=max(tol, 1e-3))


def test_physical_convention_refuses_a_microlens_narrower_than_the_pixel():
    """'physical' applies the share of the light on the microlens to the whole pixel: a microlens of 0.7-2.8 um on
    a 2.8 um pixel read 1.333x a bare pixel at the centre whatever its width (the audit's estimate for 0.7 um: about
    1.0); refused, naming the argument. ISETCam's convention (the light on the microlens) keeps it."""
    oi = _uniform_oi(9, 9, 2.8e-6, 40e-6)
    for kw in ({"microlens_diameter_m": 1.4e-6}, {"microlens_f_number": 5.0}):
        sensor = Sensor(rows=9, cols=9, pixel_size_m=2.8e-6, pixel_optics={"method": "centred", **kw})
        with pytest.raises(ValueError, match=f"{next(iter(kw))}: a microlens .* narrower than the pixel"):
            sensor.electron_rate(oi)
    iset = Sensor(rows=9, cols=9, pixel_size_m=2.8e-6,
                  pixel_optics={"method": "centred", "convention": "isetcam", "microlens_diameter_m": 1.4e-6})
    assert bool(torch.isfinite(iset.electron_rate(oi)).all())
    full = Sensor(rows=9, cols=9, pixel_size_m=2.8e-6, pixel_optics={"method": "centred",
                                                                     "microlens_diameter_m": 2.8e-6})
    assert bool(torch.isfinite(full.electron_rate(oi)).all())


def test_a_telecentric_lens_has_no_fall_off():
    """exit_pupil_distance_m=inf: every chief ray parallel to the axis, so every pixel has the on-axis etendue."""
    oi = _uniform_oi(8, 10, 2.8e-6, 20e-6)
    for convention in ("physical", "isetcam"):
        for method in ("none", "centred", "optimal"):  # (ISETCam's grid with a microlens: inf x 0 = NaN offsets)
            po = PixelOptics(method, convention=convention, exit_pupil_distance_m=math.inf)
            assert float(po.chief_ray_angle_deg(oi, 8, 10, 2.8e-6).abs().max()) == 0.0
            m = po.etendue_map(oi, 8, 10, 2.8e-6)
            on_axis = float(m.reshape(-1)[0])
            torch.testing.assert_close(m, torch.full_like(m, on_axis), rtol=0, atol=1e-12)
            if method != "none" and convention == "isetcam":
                assert on_axis == pytest.approx(1.0, abs=1e-12)  # ISETCam's pixel with its microlens, on axis
    # ISETCam's grid reads the etendue by CRA, 0 everywhere here: an offset growing with the image height is refused
    with pytest.raises(ValueError, match="offset_per_image_height: convention 'isetcam' reads"):
        PixelOptics("centred", convention="isetcam", exit_pupil_distance_m=math.inf, offset_per_image_height=0.1)
    # the physical convention places it: the microlens moves off the telecentric rays away from the axis
    po = PixelOptics("centred", exit_pupil_distance_m=math.inf, offset_per_image_height=0.1)
    m = po.etendue_map(oi, 8, 10, 2.8e-6)[0]
    assert float(m[3, 4]) > float(m[0, 0]) + 0.01
    with pytest.raises(ValueError, match="exit_pupil_distance_m"):
        PixelOptics("none", exit_pupil_distance_m=-math.inf)
    # read as a number per call: a tensor that requires grad got no gradient, silently
    with pytest.raises(ValueError, match="exit_pupil_distance_m: a fixed number of metres, not a tensor that requires"):
        PixelOptics("none", exit_pupil_distance_m=torch.tensor(2e-3, requires_grad=True))


def test_bad_pixel_values_are_refused_when_built():
    with pytest.raises(ValueError, match="chief_ray_angle_deg: expected angles in degrees, got a boolean"):
        microlens_etendue(True)
    with pytest.raises(ValueError, match="layer_thicknesses_m"):
        PixelOptics("centred", layer_thicknesses_m=(-1e-6, 2e-6))
    with pytest.raises(ValueError, match="layer_indices"):
        PixelOptics("centred", layer_indices=(0.5, 1.4))
    with pytest.raises(ValueError, match="photodiode_size_m"):
        PixelOptics("centred", pixel_size_m=2e-6, photodiode_size_m=3e-6)


def _trace_2d(cra_deg, azimuth_deg, method, n_rays=400_000, pixel_um=2.8, f_number=4.0, seed=0):
    """An independent 2-D trace of ISETCam's default pixel (NumPy): source directions uniform in the disk of
    direction sines of radius sin(atan(1 / 2N)) about the chief ray's (azimuth measured from the pixel's columns),
    entry points uniform over the pixel, ISETCam's microlens deflection sin(atan(x / f')) along each axis (mlLens,
    f' = 7 um / 1.52), then the 2 um (n 2.0) and 5 um (n 1.46) layers walked with the direction sines' components
    conserved (planar interfaces, Snell's law in 3-D); the share landing on the sqrt(0.75)-wide photodiode."""
    g = np.random.default_rng(seed)
    na = math.sin(math.atan(1 / (2 * f_number)))
    s = math.sin(math.radians(cra_deg))
    r = na * np.sqrt(g.random(n_rays))
    a = 2 * np.pi * g.random(n_rays)
    lx = s * math.cos(math.radians(azimuth_deg)) + r * np.cos(a)
    ly = s * math.sin(math.radians(azimuth_deg)) + r * np.sin(a)
    x, y = (g.random(n_rays) - 0.5) * pixel_um, (g.random(n_rays) - 0.5) * pixel_um
    if method != "none":
        f_air = 7.0 / 1.52
        lx, ly = lx + np.sin(np.arctan(x / f_air)), ly + np.sin(np.arctan(y / f_air))
    ok = lx ** 2 + ly ** 2 < 0.99 ** 2
    for t_um, n in ((2.0, 2.0), (5.0, 1.46)):
        cz = np.sqrt(np.maximum(n * n - lx ** 2 - ly ** 2, 1e-12))
        x, y = x - t_um * lx / cz, y - t_um * ly / cz
    half = math.sqrt(0.75) * pixel_um / 2
    return float((ok & (np.abs(x) < half) & (np.abs(y) < half)).mean())


@pytest.mark.parametrize(("method", "cra_deg"), [("centred", 10.0), ("centred", 20.0), ("none", 20.0)])
def test_physical_map_is_separable_along_the_pixel_axes(method, cra_deg):
    """A square pixel's etendue is separable along its columns and rows (ISETCam's pixel irradiance, mlRadiance, is
    the outer product of its x-profile): a pixel on a diagonal, whose chief ray's angle splits between the two
    axes, keeps more light than one on an axis at the same chief-ray angle (with a centred microlens at 20 deg,
    0.355 of a 2-D trace against 0.123). The map is T(|x|) T(|y|), T the 1-D etendue at the chief ray of the image
    point on an axis; it was radially symmetric, E(CRA) E(0), which read 0.188 for both pixels. On the diagonal it
    is near the 2-D trace; on an axis the 1-D model is what it was."""
    n = 9  # pixel (0, 0) is 4 pitches from the axis in x and y: on the diagonal at cra_deg
    pitch = 2.8e-6
    d = 4 * math.sqrt(2) * pitch / math.tan(math.radians(cra_deg))
    oi = _uniform_oi(n, n, pitch, d)
    m = PixelOptics(method, samples=(128, 256), angle_samples=65).etendue_map(oi, n, n, pitch)[0]
    kw = dict(samples=(128, 256), sampling="continuous")
    along = microlens_etendue(math.degrees(math.atan(4 * pitch / d)), method, **kw)
    assert float(m[0, 0]) == pytest.approx(float(along) ** 2, abs=3e-3)  # T(|x|) T(|y|)
    radial = float(microlens_etendue(cra_deg, method, **kw) * microlens_etendue(0.0, method, **kw))
    trace = _trace_2d(cra_deg, 45.0, method)
    assert abs(float(m[0, 0]) - trace) < 0.045, (float(m[0, 0]), trace)
    if method == "centred":  # where the radially symmetric map was far off
        assert abs(radial - trace) > 0.12, (radial, trace)


def test_pixel_optics_offsets_and_refusals():
    """The geometric model places the array's offset per pixel (it was dropped), method 'none' refuses an offset
    (ignored before), a boolean is no offset, and geometry read as numbers refuses a tensor that requires grad
    (its gradient was dropped)."""
    rows, cols, pitch, d = 4, 6, 2.8e-6, 20e-6
    oi = _uniform_oi(rows, cols, pitch, d)
    o = 0.05
    m = PixelOptics("centred", model="geometric", offset_per_image_height=o).etendue_map(oi, rows, cols, pitch)[0]
    plain = PixelOptics("centred", model="geometric").etendue_map(oi, rows, cols, pitch)[0]
    x, y = 2.5 * pitch, 1.5 * pitch  # pixel (0, 0)

    def geo(u):
        return float(microlens_etendue(math.degrees(math.atan(u / d)), "centred", model="geometric",
                                       offset_m=o * u))

    assert float(m[0, 0]) == pytest.approx(geo(x) * geo(y) / geo(0.0), abs=3e-3)
    assert abs(float(m[0, 0]) - float(plain[0, 0])) > 0.01
    with pytest.raises(ValueError, match="offset_per_image_height: method 'none' has no microlens"):
        PixelOptics("none", offset_per_image_height=0.1)
    bare = PixelOptics("none", learnable=True)  # the stack height still learns (it was refused, naming the offset)
    assert [n for n, _ in bare.named_parameters()] == ["log_stack_height_m"]
    bare.etendue_map(oi, rows, cols, pitch).sum().backward()
    assert float(bare.log_stack_height_m.grad.abs()) > 0
    with pytest.raises(ValueError, match="offset_per_image_height: expected a finite number"):
        PixelOptics("centred", offset_per_image_height=True)
    with pytest.raises(ValueError, match="offset_m: method 'none' has no microlens"):
        microlens_etendue(10.0, "none", model="geometric", offset_m=1e-7)
    pd = torch.tensor(2.4e-6, dtype=torch.float64, requires_grad=True)
    with pytest.raises(ValueError, match="photodiode_size_m: the etendue reads it as a number"):
        microlens_etendue(15.0, "centred", sampling="continuous", photodiode_size_m=pd)
    for ff in (1.5, float("nan"), 0.0):  # (reported as photodiode_size_m)
        with pytest.raises(ValueError, match="fill_factor: expected a number in"):
            PixelOptics("centred").etendue_map(oi, rows, cols, pitch, fill_factor=ff)
    t = torch.tensor([2e-6, 5e-6], dtype=torch.float64, requires_grad=True)
    with pytest.raises(ValueError, match="sampling: 'isetcam'"):
        microlens_etendue(15.0, "centred", layer_thicknesses_m=t)


def test_spectral_etendue_rates_are_each_bands_1d_profiles_at_the_pixels_coordinates():
    # 'physical': a pixel at column coordinate x and row coordinate y gets T_l(|x|) T_l(|y|) in band l, T_l linear
    # between the radial samples (NumPy's interp here); the channel rates are sum_l sample_l * map_l * qe_l, with a
    # gradient to the stack height equal to the central difference (a non-square sensor, a non-uniform image)
    rows, cols, pitch = 5, 9, 1.4e-6
    waves = torch.tensor([450.0, 550.0, 650.0])
    g = torch.Generator().manual_seed(3)
    photons = 1e15 * (0.5 + torch.rand(1, 3, rows, cols, generator=g, dtype=torch.float64))
    oi = OpticalImage(photons, waves, sample_spacing_m=torch.tensor([pitch], dtype=torch.float64),
                      focal_length_m=torch.tensor([40e-6]), image_distance_m=torch.tensor([40e-6]),
                      f_number=torch.tensor([2.0]))
    po = {"method": "centred", "diffraction": True, "layer_thicknesses_m": [1e-6, 2e-6],
          "layer_indices": [1.46, 1.6], "microlens_focal_length_m": 3e-6, "angle_samples": 7, "learnable": True}
    s = Sensor(rows=rows, cols=cols, pixel_size_m=pitch, cfa="RGGB", pixel_optics=po).double()
    e, _, _ = s.pixel_optics.radial_etendue(oi, rows, cols, pitch, s.fill_factor)
    e = e.detach()[0].numpy()  # [L, K]
    rk = np.linspace(0.0, (max(rows, cols) - 1) / 2 * pitch, e.shape[-1])
    x = np.abs(np.arange(cols) - (cols - 1) / 2) * pitch
    y = np.abs(np.arange(rows) - (rows - 1) / 2) * pitch
    want = np.stack([np.interp(y, rk, e[i])[:, None] * np.interp(x, rk, e[i])[None, :] for i in range(3)])
    emap = s.etendue_map(oi)[0].detach().numpy()
    np.testing.assert_allclose(emap, want, rtol=1e-12)
    assert emap[0, 2, 4] > emap[0, 0, 0]  # (not flat: the field falls off)
    sampled = s.sample(oi.photons, oi)[0].detach().numpy()  # [L, rows, cols]
    qe = s.spectral_weights(oi).detach().numpy()  # [L, C]
    rates, _ = s.channel_rates(oi)
    area = pitch ** 2  # 'physical': the whole pixel's light meets the etendue (which holds the photodiode's width)
    np.testing.assert_allclose(rates[0].detach().numpy(), area * np.einsum("lrc,lk->krc", sampled * want, qe),
                               rtol=1e-12)

    h = s.pixel_optics.log_stack_height_m
    total = s.channel_rates(oi)[0].sum()
    (grad,) = torch.autograd.grad(total, h)
    assert float(grad) == pytest.approx(central_difference(lambda: s.channel_rates(oi)[0].sum(), h, 1e-5), rel=1e-5)
    assert abs(float(grad)) > 0

    # the filters' gradient through the per-band accumulation: d rates_c / d qe[l, c] = area * sampled_l * map_l,
    # so a learnable QE's raw parameters get autograd's value, each entry against its central difference
    qe_mod = SpectralQE.from_cfa(CFA("RGGB"), learnable=True, wavelengths_nm=waves).double()
    wgt = torch.rand(1, 3, rows, cols, generator=g, dtype=torch.float64)  # (a weighted loss: every pixel counts)

    def loss():
        return (s.channel_rates(oi, spectral_qe=qe_mod)[0] * wgt).sum()

    (g_raw,) = torch.autograd.grad(loss(), qe_mod.raw_filters)
    for c, band in ((0, 0), (1, 1), (2, 2), (0, 2)):
        fd = central_difference(loss, qe_mod.raw_filters.data[c, band], 1e-6)
        assert float(g_raw[c, band]) == pytest.approx(fd, rel=1e-6)
        assert abs(fd) > 0


def test_the_geometric_model_is_not_counted_twice_under_the_physical_convention():
    """The geometric model is already a 2-D efficiency (both axes' overlaps); the separable map multiplied the other
    axis's on-axis share in again: a bare pixel's centre got T(0)^2 = 0.485 instead of T(0) = 0.696."""
    rows, cols, pitch, d = 9, 9, 2.8e-6, 30e-6
    oi = _uniform_oi(rows, cols, pitch, d)
    for method in ("none", "centred"):
        m = PixelOptics(method, model="geometric").etendue_map(oi, rows, cols, pitch)[0]

        def geo(u, method=method):
            return float(microlens_etendue(math.degrees(math.atan(u / d)), method, model="geometric",
                                           pixel_size_m=pitch))

        assert float(m[4, 4]) == pytest.approx(geo(0.0), rel=1e-9)  # the axis: the 2-D model itself
        assert float(m[4, 8]) == pytest.approx(geo(4 * pitch), rel=1e-3)  # (interpolated between heights)
        assert float(m[0, 4]) == pytest.approx(float(m[4, 0]), rel=1e-12)
        if method == "centred":
            assert float(m[4, 4]) == pytest.approx(1.0)  # a centred microlens keeps all the light at normal incidence


def test_physical_pixel_optics_gather_the_light_over_the_whole_pixel():
    """The microlens (as wide as the pixel) gathers the light on the whole pixel, and the physical convention scales by
    the whole pixel's area, but the irradiance was averaged over the photodiode's square only: light falling between
    the photodiodes (19 % of the area at fill 0.75) was dropped and light on them counted 1/0.75 times."""
    from isettorch.sensor import Sensor

    rows = cols = 4
    pitch, sub = 2.8e-6, 20
    dx, n = pitch / sub, (rows + 2) * sub  # 20 samples per pixel, one pixel of margin
    c = (torch.arange(n, dtype=torch.float64) - (n - 1) / 2) * dx
    cell = torch.remainder(c + (rows - 1) / 2 * pitch + pitch / 2, pitch) - pitch / 2  # offset from the pixel centre
    half = math.sqrt(0.75) * pitch / 2
    on1 = cell.abs() < half - dx / 2
    off1 = cell.abs() > half + dx / 2
    masks = {"all": torch.ones(n, n, dtype=torch.bool), "on": on1[:, None] & on1[None, :],
             "between": off1[:, None] | off1[None, :]}

    def rate(mask):
        oi = OpticalImage((1e15 * mask.double())[None, None], torch.tensor([550.0]),
                          sample_spacing_m=torch.tensor([dx], dtype=torch.float64), focal_length_m=torch.tensor([1.0]),
                          image_distance_m=torch.tensor([1.0]), f_number=torch.tensor([8.0]))  # chief rays ~ 0 deg
        s = Sensor(rows=rows, cols=cols, pixel_size_m=pitch, fill_factor=0.75, exposure_s=1e-3,
                   pixel_optics={"method": "centred"})
        assert float(s.etendue_map(oi)[0, 1, 1]) == pytest.approx(1.0, abs=1e-6)
        return float(s.electron_rate(oi)[0, 0, 1, 1])

    lit = {k: float(m[2 * sub:3 * sub, 2 * sub:3 * sub].double().mean()) for k, m in masks.items()}  # pixel (1, 1)
    assert lit["on"] == pytest.approx(0.64) and lit["between"] == pytest.approx(0.19)  # (samples on the edge: neither)
    full = rate(masks["all"])
    for k in ("on", "between"):  # the signal is the lit share of the pixel's
        assert rate(masks[k]) == pytest.approx(full * lit[k], rel=1e-9), k


def test_pixel_optics_refuse_an_index_below_one_a_boolean_and_a_mismatched_offset():
    """stack_index 0.5 gave NaN at 40 deg and silent zeros (no refracted ray past sin(theta) = n), f_number True was
    f/1, microlens_offset_m raised math's unnamed 'math domain error', offset_m=True was a 1 m offset, and offsets
    of another shape raised torch's broadcast error naming no argument."""
    from isettorch.sensor.pixel_optics import microlens_offset_m

    for microlens in (False, True):
        with pytest.raises(ValueError, match=r"stack_index: expected a refractive index >= 1, got 0.5"):
            pixel_vignetting(torch.tensor([0.0, 20.0, 40.0]), 4.0, 7e-6, 2.8e-6, 2.42e-6, stack_index=0.5,
                             microlens=microlens)
    with pytest.raises(ValueError, match=r"f_number: expected a positive number, got True"):
        pixel_vignetting(0.0, True, 7e-6, 2.8e-6, 2.42e-6)
    with pytest.raises(ValueError, match=r"stack_index: expected a refractive index >= 1"):
        microlens_offset_m(40.0, 7e-6, 0.5)
    # Snell: the offset is -h tan(asin(sin(theta) / n))
    assert microlens_offset_m(30.0, 7e-6, 1.0) == pytest.approx(-7e-6 * math.tan(math.radians(30.0)), rel=1e-12)
    for sampling in ("isetcam", "continuous"):
        with pytest.raises(ValueError, match=r"offset_m: expected finite offsets \(m\), got True"):
            microlens_etendue(torch.tensor([0.0]), "centred", offset_m=True, sampling=sampling)
    with pytest.raises(ValueError, match=r"offset_m: shape \(3,\) does not broadcast with the chief-ray angles'"):
        microlens_etendue(torch.tensor([0.0, 10.0]), "centred", offset_m=torch.tensor([0.0, 1e-7, 2e-7]))


def test_pixel_values_given_as_tensors_are_cached_by_value():
    """The etendue map was memoised by the pixel values' identity: an optimiser's in-place step on a learnable
    microlens focal length returned the old map (0.53 off a fresh module's) and a graph already freed; an in-place
    change of a source f-number tensor (4 -> 1.4) the old map too (0.51 off). Each now equals a fresh module's."""
    oi = _uniform_oi(6, 8, 2.8e-6, 30e-6, waves=torch.tensor([550.0]))
    f = torch.nn.Parameter(torch.tensor(7e-6, dtype=torch.float64))
    po = PixelOptics("centred", microlens_focal_length_m=f)
    po.etendue_map(oi, 6, 8, 2.8e-6).sum().backward()
    with torch.no_grad():
        f.fill_(3e-6)
    again = po.etendue_map(oi, 6, 8, 2.8e-6)
    fresh = PixelOptics("centred", microlens_focal_length_m=3e-6).etendue_map(oi, 6, 8, 2.8e-6)
    assert float((again - fresh).abs().max()) == 0.0
    again.sum().backward()  # (a new graph)
    fn = torch.tensor(4.0, dtype=torch.float64)
    po = PixelOptics("centred", source_f_number=fn)
    old = po.etendue_map(oi, 6, 8, 2.8e-6)
    fn.fill_(1.4)
    fresh = PixelOptics("centred", source_f_number=1.4).etendue_map(oi, 6, 8, 2.8e-6)
    assert float((po.etendue_map(oi, 6, 8, 2.8e-6) - fresh).abs().max()) == 0.0
    assert float((old - fresh).abs().max()) > 0.1


def test_stack_height_is_one_value_and_a_learnable_one_is_named():
    """Two stack heights were applied to the two layers (a 3.14 um stack for [1, 4] um: 0.672 at both angles, where
    1 um and 4 um give 0.858 and 0.618); a tensor that requires grad had its gradient dropped with a torch warning."""
    with pytest.raises(ValueError, match=r"stack_height_m: expected one value .* got shape \(2,\)"):
        microlens_etendue(torch.tensor([20.0, 20.0]), "none", stack_height_m=torch.tensor([1e-6, 4e-6]))
    h = torch.tensor(4e-6, dtype=torch.float64, requires_grad=True)  # one value keeps its gradient
    e = microlens_etendue(torch.tensor(20.0, dtype=torch.float64), "none", stack_height_m=h, sampling="continuous")
    e.backward()
    assert h.grad is not None and float(h.grad) < 0  # a taller stack loses more of an oblique beam
    with pytest.raises(ValueError, match="stack_height_m: the starting height, .* learnable=True"):
        PixelOptics("centred", stack_height_m=torch.tensor(5e-6, dtype=torch.float64, requires_grad=True))


def test_the_sensor_and_its_pixel_optics_have_one_photodiode():
    """fill_factor 0.3 with pixel optics of a 75 % photodiode rendered 2.5x the plain sensor's rate through a
    vanishing stack (the etendue took one photodiode, the rate the other; ISETCam's pixel has one): refused,
    naming both; an agreeing photodiode is accepted and a vanishing stack then leaves the rate unchanged."""
    kw = dict(rows=5, cols=7, read_noise_v=0.0, dark_current_e_per_s=0.0, pixel_size_m=2.8e-6, fill_factor=0.3)
    po = {"method": "none", "stack_height_m": 1e-10}
    with pytest.raises(ValueError, match=r"pixel_optics.photodiode_size_m: .* fill factor of 0.75, not the "
                                         r"sensor's fill_factor 0.3"):
        Sensor(pixel_optics={**po, "photodiode_size_m": 2.8e-6 * math.sqrt(0.75)}, **kw)
    oi = _uniform_oi(5, 7, 2.8e-6, 30e-6, waves=torch.tensor([450.0, 550.0, 650.0]))
    plain = Sensor(**kw).electron_rate(oi)
    same = Sensor(pixel_optics={**po, "photodiode_size_m": 2.8e-6 * math.sqrt(0.3)}, **kw).electron_rate(oi)
    assert float((same / plain)[0, 0, 2, 3]) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("kw, name", [(dict(source_focal_length_m=math.nan), "source_focal_length_m"),
                                      (dict(microlens_index=0.3), "microlens_index"),
                                      (dict(model="geometric", wavelength_nm=math.nan), "wavelength_nm"),
                                      (dict(model="geometric", microlens_focal_length_m=math.nan),
                                       "microlens_focal_length_m")])
def test_pixel_values_the_etendue_does_not_read_are_checked_as_pixel_optics_checks_them(kw, name):
    """microlens_etendue returned 1.0 for a NaN source focal length or an index of 0.3 (PixelOptics refuses both)."""
    with pytest.raises(ValueError, match=f"^{name}: expected"):
        microlens_etendue(0.0, "centred", **kw)
    with pytest.raises(ValueError, match="rows, cols: expected positive integers, got True"):
        microlens_array_offsets_m(True, 2, 2.8e-6)


def test_the_geometric_model_refuses_a_microlens_it_does_not_model():
    """model='geometric' (Catrysse & Wandell's closed form) has an ideal microlens as wide as the pixel, focused at the
    stack's depth; a microlens half or twice the pixel's width, or of f-number 1, gave the etendue of the default one
    (0.3166 at 20 deg, f/2) without a word. Now each names its argument; the default and an explicit pixel-wide
    microlens give pixel_vignetting's value."""
    base = dict(pixel_size_m=2.8e-6, source_f_number=2.0)
    cra = torch.tensor([0.0, 20.0])
    ref = microlens_etendue(cra, "centred", model="geometric", **base)
    same = microlens_etendue(cra, "centred", model="geometric", microlens_diameter_m=2.8e-6, **base)
    torch.testing.assert_close(same, ref, rtol=0, atol=0)
    for name, value in (("microlens_diameter_m", 1.4e-6), ("microlens_diameter_m", 5.6e-6),
                        ("microlens_f_number", 1.0), ("microlens_focal_length_m", 1e-6)):
        with pytest.raises(ValueError, match=rf"^{name}: model 'geometric' has "):
            microlens_etendue(cra, "centred", model="geometric", **{name: value}, **base)
