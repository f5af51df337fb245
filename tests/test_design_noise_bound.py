"""The noise-limited colour estimate (:func:`isettorch.design.colour_estimate_mse`,
:func:`~isettorch.design.patch_signals`) against closed forms and finite differences, and the shipped designs'
captures benchmarks/design_noise_bound.py reads (issue #36)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import design_noise_bound as dnb  # noqa: E402  benchmarks/design_noise_bound.py (not part of the package)

from isettorch.design import SHIPPED_DESIGNS, design_path  # noqa: E402


def test_wiener_mse_matches_the_scalar_closed_form():
    # one channel whose mean is the target in each sRGB channel: the Wiener gain is q / (q + s) with q = E[rho^2] and
    # s the noise variance of the mean, and the error s q / (q + s) (Kay 1993, 12.6); s = 0 gives 0
    g = torch.Generator().manual_seed(0)
    rho = torch.rand(24, 1, generator=g, dtype=torch.float64) * 40
    target = rho.expand(24, 3) / 40
    var, frac, window = torch.full((24, 1), 30.0, dtype=torch.float64), torch.tensor([0.5], dtype=torch.float64), 16
    s = 30.0 / (0.5 * 16) / 40**2  # in the target's units
    q = float((target[:, 0] ** 2).mean())
    got = dnb.wiener_mse(rho, var, frac, target, window)
    assert got == pytest.approx(s * q / (q + s), rel=1e-12)
    assert dnb.wiener_mse(rho, torch.zeros_like(var), frac, target, window) == pytest.approx(0.0, abs=1e-20)
    # more light (the same noise, 4x the signal) always lowers the error
    assert dnb.wiener_mse(4 * rho, var, frac, target, window) < got


@pytest.mark.skipif(not all(design_path(n).is_file() for n in SHIPPED_DESIGNS), reason="no shipped designs")
def test_design_capture_counts_photons_of_the_mosaic_channels():
    # Bayer at 10 lux: three channels on 1/4, 1/2, 1/4 of the pixels; ten times the light gives ten times the
    # electrons at the same exposure (1/30 s, the limit, at both levels: the gain differs, not the photons)
    from isettorch.design import load_design

    cam = load_design("bayer_rgb").eval()
    lo, hi = dnb.channel_electrons(cam, 1.0), dnb.channel_electrons(cam, 10.0)
    assert sorted(lo["frac"].tolist()) == [0.25, 0.25, 0.5]
    assert lo["exposure_s"] == pytest.approx(1 / 30) and hi["exposure_s"] == pytest.approx(1 / 30)
    torch.testing.assert_close(hi["rho"], 10 * lo["rho"], rtol=1e-6, atol=0)
    assert lo["rho"].shape == (24, 3) and bool((lo["rho"] > 0).all())


def test_colour_correction_learned_on_one_set_and_applied_to_another_matches_the_closed_form():
    # noise-free channels that are a linear transform A of the target on the fit set: the Wiener map is A^-1, so a
    # test set whose channels are T B gives the error mean((T B A^-1 - T)^2) exactly, and B = A gives 0
    from isettorch.design import colour_estimate_mse

    g = torch.Generator().manual_seed(3)
    t_fit, t_test = (torch.rand(n, 3, generator=g, dtype=torch.float64) for n in (40, 25))
    a = torch.rand(3, 3, generator=g, dtype=torch.float64) + 2 * torch.eye(3, dtype=torch.float64)
    b = a + 0.1 * torch.rand(3, 3, generator=g, dtype=torch.float64)
    zero = {"frac": torch.full((3,), 1 / 3, dtype=torch.float64)}
    fit = {"rho": t_fit @ a, "var": torch.zeros(40, 3, dtype=torch.float64), "target": t_fit, **zero}
    same = {"rho": t_test @ a, "var": torch.zeros(25, 3, dtype=torch.float64), "target": t_test, **zero}
    other = dict(same, rho=t_test @ b)
    assert float(colour_estimate_mse(fit, 16, same)) == pytest.approx(0.0, abs=1e-24)
    want = float(((t_test @ b @ torch.linalg.inv(a) - t_test) ** 2).mean())
    assert float(colour_estimate_mse(fit, 16, other)) == pytest.approx(want, rel=1e-9)
    # the noise term is the test set's: trace(M S M') / 3 with S its variance over the window
    noisy = dict(same, var=torch.full((25, 3), 12.0, dtype=torch.float64))
    m = torch.linalg.inv(a).T
    assert float(colour_estimate_mse(fit, 16, noisy)) == pytest.approx(float((m**2).sum()) * 12 / (16 / 3) / 3,
                                                                       rel=1e-9)
    # bad signals are named (they gave NaN, a KeyError or a bare matmul / solver error)
    with pytest.raises(ValueError, match=r"^fit: expected every channel in the mosaic cell \(frac > 0\)"):
        colour_estimate_mse(dict(fit, frac=torch.tensor([0.5, 0.5, 0.0], dtype=torch.float64)), 16)
    with pytest.raises(ValueError, match=r"^test: expected rho \[n >= 1, 3\]"):
        colour_estimate_mse(fit, 16, dict(same, rho=same["rho"][:, :2]))
    with pytest.raises(ValueError, match=r"^fit: expected patch_signals' mapping .* missing \['var'\]"):
        colour_estimate_mse({k: v for k, v in fit.items() if k != "var"}, 16)
    with pytest.raises(ValueError, match=r"^fit: the Wiener system is singular"):
        colour_estimate_mse(dict(fit, rho=torch.zeros(40, 3, dtype=torch.float64)), 16)
    with pytest.raises(ValueError, match="window"):
        colour_estimate_mse(fit, 0)


def test_patch_signals_gradient_matches_finite_differences():
    # d(error)/d(filter parameter) through the capture (exposure rule, hard mosaic), float64, central differences
    from isettorch.design import colour_estimate_mse, make_design, patch_signals
    from isettorch.scene.macbeth import macbeth_reflectances

    spec = {"filters": ["learned", "learned", "learned"], "mosaic_init": [["F1", "F0"], ["F2", "F1"]]}
    cam = make_design(spec).eval()
    refl = macbeth_reflectances(cam.wavelengths_nm, dtype=torch.float64)

    def err():
        sig = patch_signals(cam, refl, 1.0, size=12)
        return colour_estimate_mse(sig, 16)

    p = cam.bank.raw_amplitudes
    p.grad = None
    err().backward()
    grad = p.grad[1, 3].item()
    h = 1e-5
    with torch.no_grad():
        p[1, 3] += h
        up = float(err())
        p[1, 3] -= 2 * h
        down = float(err())
        p[1, 3] += h
    assert grad == pytest.approx((up - down) / (2 * h), rel=1e-4)
    with pytest.raises(ValueError, match="reflectance"):
        patch_signals(cam, refl[:, :5], 1.0)


def test_bound_patches_lift_colours_as_photographs_are_lifted():
    # the "photo" set is colours in Mallett & Yuksel's basis: their linear sRGB under D65 gives the colours back
    # (to the basis' 10-nm accuracy, as the photos source's targets); the sets depend on the seed only
    from isettorch.data.spectra import srgb_basis_spectra
    from isettorch.design import bound_patches, linear_srgb_of_reflectance

    wl = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    a, b = bound_patches(wl, 40, 30, seed=2), bound_patches(wl, 40, 30, seed=2)
    assert {k: tuple(v.shape) for k, v in a.items()} == {"fit": (40, 31), "macbeth": (24, 31), "photo": (30, 31)}
    for k in a:
        assert torch.equal(a[k], b[k]), k
    assert not torch.equal(bound_patches(wl, 40, 30, seed=3)["fit"], a["fit"])
    assert bool(((a["fit"] >= 0) & (a["fit"] <= 1)).all())
    # the colours, recovered from the lifted spectra by least squares on the basis
    basis = srgb_basis_spectra(wl).to(torch.float64)
    colours = torch.linalg.lstsq(basis.T, a["photo"].T).solution.T
    assert bool(((colours > -1e-9) & (colours < 1 + 1e-9)).all())
    torch.testing.assert_close(linear_srgb_of_reflectance(a["photo"], wl), colours, rtol=0, atol=0.011)
    with pytest.raises(ValueError, match="test_colours"):
        bound_patches(wl, 40, 0)


def test_patch_signals_reads_whole_mosaic_cells():
    # an 8 x 8 mosaic: the default window holds whole cells, so each channel's share is the cell's and every channel
    # the cell uses has a mean; a window that would cut cells is refused
    from isettorch.design import make_design, patch_signals
    from isettorch.scene.macbeth import macbeth_reflectances

    cam = make_design({"filters": ["learned", "learned", "W"], "mosaic_shape": [8, 8]}).eval()
    cell = cam.mosaic.index_map
    refl = macbeth_reflectances(cam.wavelengths_nm, dtype=torch.float64)[:3]
    with torch.no_grad():
        sig = patch_signals(cam, refl, 10.0)
    used = [c for c in range(3) if bool((cell == c).any())]
    assert sig["frac"].tolist() == [float((cell == c).double().mean()) for c in used]
    assert sig["rho"].shape == (3, len(used)) and bool(torch.isfinite(sig["rho"]).all())
    with pytest.raises(ValueError, match="size"):
        patch_signals(cam, refl, 10.0, size=20)  # a 12-pixel window cuts the 8-pixel cells


def test_patch_signals_of_named_sets_equal_separate_captures():
    # sets captured together read what each set's own capture reads (the exposure is the light's, not the
    # patches'), to float rounding (one batch against three)
    from isettorch.design import load_design, patch_signals
    from isettorch.scene.macbeth import macbeth_reflectances

    cam = load_design("learned")
    refl = macbeth_reflectances(cam.wavelengths_nm, dtype=torch.float64)
    sets = {"a": refl[:5], "b": refl[5:6], "c": refl[6:]}
    with torch.no_grad():
        together = patch_signals(cam, sets, 1.0)
        for name, r in sets.items():
            alone = patch_signals(cam, r, 1.0)
            assert together[name]["names"] == alone["names"] and together[name]["exposure_s"] == alone["exposure_s"]
            for key in ("rho", "var", "target", "frac"):
                torch.testing.assert_close(together[name][key], alone[key], rtol=1e-12, atol=0)


def test_predesign_filters_is_adam_on_the_colour_bound():
    # the library's filter design: the record's end loss is the criterion after the last step, lower than at the
    # start; its gain over Bayer is the difference of the two criteria in dB; a fixed design is refused
    from isettorch.design import bound_patches, colour_bound_loss, make_design, predesign_filters

    cam = make_design({"filters": ["learned"] * 3, "mosaic_shape": [2, 2],
                       "mosaic_init": [["F1", "F0"], ["F2", "F1"]]})
    rec = predesign_filters(cam, [1.0], steps=4, fit_patches=24, test_colours=12)
    patches = bound_patches(cam.wavelengths_nm, 24, 12, 5)
    with torch.no_grad():
        end = float(colour_bound_loss(cam.eval(), patches, [1.0]))
        bayer = float(colour_bound_loss(make_design("bayer_rgb").eval(), patches, [1.0]))
    assert rec["loss"][1] == pytest.approx(end, rel=1e-12) and end < rec["loss"][0]
    assert rec["gain_db"]["1"] == pytest.approx(10 / math.log(10) * (bayer - end), abs=1e-3)
    with pytest.raises(ValueError, match="learned filters"):
        predesign_filters(make_design("bayer_rgb"), [1.0], steps=1)


def _bound_and_measured(sensor: dict, seed: int) -> tuple[dict, list[float]]:
    """patch_signals of a white patch at 1 lux through Bayer with ``sensor``'s settings, and each used channel's
    per-pixel variance in electrons measured on 16 noisy frames of it (64 x 64 read pixels each: the spread about
    each frame's channel mean, over the output's DN per electron squared)."""
    from isettorch.design import make_design, patch_signals
    from isettorch.scene.macbeth import macbeth_reflectances

    cam = make_design("bayer_rgb", {"sensor": sensor} if sensor else None)
    white = macbeth_reflectances(cam.wavelengths_nm, dtype=torch.float64)[18:19]
    sig = patch_signals(cam, white, 1.0, size=72)
    n = 16
    cap = cam.capture(cam.scene(torch.ones(n, 1, 72, 72, dtype=torch.float64), white.expand(n, -1)[:, None], 1.0),
                      generator=torch.Generator().manual_seed(seed))
    dn = cap["raw"].data[:, 0, 4:-4, 4:-4]
    k = float(cam.sensor.gain_per_electron(sig["gain"])[0])  # DN per electron
    read = cam.mosaic.index_map.repeat(36, 36)[4:-4, 4:-4]
    measured = []
    for name in sig["names"]:
        v = dn[:, read == cam.bank.channel_names.index(name)]
        measured.append(float(((v - v.mean(1, keepdim=True)) ** 2).sum() / (v.numel() - n)) / k**2)
    return sig, measured


@pytest.mark.parametrize("sensor", [{}, {"cds": True}, {"dsnu_sigma_v": 5e-4}])
def test_patch_signals_variance_is_the_captures(sensor):
    """The bound's per-pixel variance is the capture's (Sensor.poisson_gaussian's dark floor): a white patch at
    1 lux through Bayer, the spread over pixels of 16 noisy frames (64 x 64 read pixels each; standard errors
    0.8-1.1 %). A formula of its own (read noise, dark signal, ADC step) gave 52.2 / 31.7 / 27.2 e^2 whatever
    the sensor: 8-15 % low with CDS (its read noise is sampled twice) and 30-48 % low with DSNU."""
    sig, measured = _bound_and_measured(sensor, seed=0)
    for k, name in enumerate(sig["names"]):
        assert float(sig["var"][0, k]) == pytest.approx(measured[k], rel=0.04), name


def test_patch_signals_variance_without_shot_noise_is_the_dark_floor():
    """A sensor with shot noise off: the per-pixel variance is the capture's dark floor alone (its spread over 16
    frames of a white patch: 100 e^2 of read noise), not the signal's 48 e- plus it (it raised an error)."""
    sig, measured = _bound_and_measured({"shot_noise": "off", "read_noise_v": 1e-3}, seed=1)
    for k in range(len(sig["names"])):
        assert float(sig["var"][0, k]) == pytest.approx(measured[k], rel=0.04)  # (with rho added: 1.5x)
