"""Camera training pairs: target consistency, noise statistics, colour targets vs colour-science."""

import colour
import numpy as np
import pytest
import torch

from isettorch.data.camera_pairs import CameraPairDataset, collate_pairs
from isettorch.sensor import CFA

SCENE = {"height": 32, "width": 32, "wavelengths_nm": [400.0, 700.0, 20.0]}


@pytest.fixture(scope="module")
def items():
    ds = CameraPairDataset(4, seed=5, scene=SCENE, camera={"cfa_patterns": ["RGGB", "GBRG", "GRBG", "BGGR"],
                                                           "qe_variation": 1.0})
    return ds, [ds[i] for i in range(4)]


def test_shapes_and_ranges(items):
    _, its = items
    for it in its:
        assert it["raw"].shape == (1, 32, 32) and it["noise_free_raw"].shape == (1, 32, 32)
        for k in ("camera_rgb", "xyz", "linear_srgb", "srgb"):
            assert it[k].shape == (3, 32, 32) and it[k].dtype == torch.float32
        assert 0.0 <= float(it["camera_rgb"].min()) and float(it["camera_rgb"].max()) <= 1.0
        assert 0.0 <= float(it["srgb"].min()) and float(it["srgb"].max()) <= 1.0
        assert float(it["noise_free_raw"].max()) <= 1.0 + 1e-6


def test_camera_rgb_mosaic_is_the_sensor_noise_free_raw(items):
    """The demosaic target, sampled by the item's CFA, is exactly the Sensor's noise_free output."""
    _, its = items
    for it in its:
        cfa_map = it["meta"]["cfa"]
        letters = "".join("RGB"[int(i)] for i in cfa_map.flatten())
        mos = CFA(letters).mosaic(it["camera_rgb"][None])[0]
        torch.testing.assert_close(mos, it["noise_free_raw"], rtol=1e-5, atol=1e-6)


def test_noise_matches_poisson_gaussian_model():
    """var(raw - noise_free) = noise_gain * signal + noise_floor_var (Foi et al. 2008), PRNU off, no clipping."""
    ds = CameraPairDataset(2, seed=1, scene={**SCENE, "height": 64, "width": 64, "hdr_decades": [0.0, 0.0],
                                             "wavelengths_nm": [400.0, 700.0, 50.0]},
                           camera={"prnu_sigma_percent": [0.0, 0.0], "exposure_ev": [-2.0, -1.5],
                                   "read_noise_e": [2.0, 6.0], "analog_gain": [1.0, 4.0]})
    for i in range(2):
        it = ds[i]
        m = it["meta"]
        resid = (it["raw"] - it["noise_free_raw"]).double()
        pred = m["noise_gain"].double() * it["noise_free_raw"].double() + m["noise_floor_var"].double()
        # mean of resid^2 / var is 1 +- sqrt(2 / 4096) ~ 2 % for Gaussian-like noise
        ratio = float((resid**2 / pred).mean())
        assert ratio == pytest.approx(1.0, abs=0.06)  # 3 standard errors


def test_xyz_white_normalisation_and_srgb_match_colour(items):
    _, its = items
    it = its[0]
    m = it["meta"]
    white_xyz = m["white_xyz"].double().numpy()
    # CIE XYZ -> Bradford CAT (light 1's white -> D65) -> sRGB, by colour-science, on a few pixels
    xyz = it["xyz"].double().permute(1, 2, 0).reshape(-1, 3).numpy()[:50]
    d65 = colour.xy_to_XYZ(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
    adapted = colour.adaptation.chromatic_adaptation_VonKries(xyz, white_xyz, d65, transform="Bradford")
    ref = colour.XYZ_to_RGB(adapted, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_encoding=False)
    ours = it["linear_srgb"].double().permute(1, 2, 0).reshape(-1, 3).numpy()[:50]
    np.testing.assert_allclose(ours, ref, rtol=2e-3, atol=2e-4 * float(np.abs(ref).max()))
    enc = colour.cctf_encoding(np.clip(ours, 0, 1), function="sRGB")
    np.testing.assert_allclose(it["srgb"].permute(1, 2, 0).reshape(-1, 3).numpy()[:50], enc, atol=1e-5)


def test_a_grey_scene_has_y_equal_to_its_green_response_and_renders_neutral(monkeypatch):
    """The targets' shared scale and colour, on a scene whose answer is known: every surface the same grey (0.4) under
    one daylight. At every unclipped pixel the XYZ target's Y equals the normalised green camera value (a perfect
    white under the light maps to Y = its green response); the light's white has the CIE daylight chromaticity of
    its CCT (colour-science); and the linear sRGB target, adapted to D65, is neutral with R = G = B = Y."""
    from isettorch.data import scenes

    monkeypatch.setattr(scenes._spectra, "random_reflectances",
                        lambda n, wl, g, **kw: torch.full((n, len(wl)), 0.4, dtype=torch.float64))
    ds = CameraPairDataset(3, seed=2, scene={**SCENE, "wavelengths_nm": [400.0, 700.0, 10.0], "illuminants":
                                             {"daylight": 1.0}, "two_light_probability": 0.0, "shadow_probability": 0.0,
                                             "hdr_decades": [0.0, 0.0]}, dtype=torch.float64)
    for i in range(3):
        it = ds[i]
        cam, xyz, lin = it["camera_rgb"], it["xyz"], it["linear_srgb"]
        ok = (cam < 0.95).all(0)  # below the clip in every channel
        assert int(ok.sum()) > 500
        torch.testing.assert_close(xyz[1][ok], cam[1][ok], rtol=1e-6, atol=0)  # (float32 inside: 1e-7)
        white = it["meta"]["white_xyz"].numpy()
        xy_ref = colour.temperature.CCT_to_xy_CIE_D(float(it["meta"]["cct_k"]))
        np.testing.assert_allclose(white[:2] / white.sum(), xy_ref, atol=2e-3)
        for c in (0, 2):
            torch.testing.assert_close(lin[c][ok], xyz[1][ok], rtol=1e-5, atol=0)


def test_metadata_collate_and_determinism(items):
    ds, its = items
    batch = collate_pairs(its[:3])
    assert batch["raw"].shape == (3, 1, 32, 32)
    assert batch["meta"]["exposure_s"].shape == (3,) and batch["meta"]["cfa"].shape == (3, 2, 2)
    assert batch["meta"]["index"].tolist() == [0, 1, 2]
    assert batch["meta"]["qe"].shape == (3, 3, 16)
    assert float(batch["meta"]["iso"][0]) == pytest.approx(100 * float(batch["meta"]["analog_gain"][0]))
    again = ds[2]
    for k in ("raw", "noise_free_raw", "camera_rgb", "xyz", "srgb"):
        assert torch.equal(again[k], its[2][k])


def test_bad_config():
    with pytest.raises(ValueError, match="camera.shutter"):
        CameraPairDataset(2, camera={"shutter": 1})
    with pytest.raises(ValueError, match="even"):
        CameraPairDataset(2, scene={"height": 31})
