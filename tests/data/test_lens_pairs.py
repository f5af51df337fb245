"""Camera pairs through a real lens (issue 16: a config makes training pairs through a ray-traced lens): the pairs
are `Camera(scene)` with the LensOptics of ``camera.optics``, and the lens's relative illumination shows from the
centre to the corner of the sensor."""

import math
from pathlib import Path

import pytest
import torch

pytest.importorskip("opticalglass")

from isettorch.data.camera_pairs import CameraPairDataset, camera_for  # noqa: E402
from isettorch.data.config import load_config  # noqa: E402
from isettorch.optics.lens.optics import LensOptics  # noqa: E402
from isettorch.scene import Scene  # noqa: E402

# a coarse lens model (few fields, pupil samples and eigen-PSFs, 7 bands) keeps the planning to seconds
LENS = {"type": "lens", "lens": "cooke_triplet", "components": 4, "field_samples": 5, "pupil_samples": 32,
        "ri_samples": 24}
PITCH_M = 5e-4  # 32 px + 2 x 8 margin of 0.5 mm: scene corners at 18.8 deg of the lens's 20 deg field
SCENE = {"height": 32, "width": 32, "wavelengths_nm": [400.0, 700.0, 50.0], "generator": "natural",
         "natural": {"components": {"dead_leaves": {"leaves": [40, 80]}}}}
CAMERA = {"optics": LENS, "pixel_size_m": [PITCH_M], "cfa_patterns": ["RGGB"], "exposure_ev": [-1.0, -1.0]}


@pytest.fixture(scope="module")
def dataset():
    return CameraPairDataset(2, seed=3, scene=SCENE, camera=CAMERA)


def test_lens_pairs_are_the_camera_with_the_lens(dataset):
    batch = dataset.get_batch([0, 1])
    for i in range(2):
        camera, scene, kw = camera_for(i, 3, dataset.scene_config, dataset.camera_config, cache=dataset._cache)
        assert isinstance(camera.optics, LensOptics)
        # the lens's own f-number and focal length (Cooke triplet: EFL 50 mm, f/5), not the drawn defaults
        assert float(batch["meta"]["focal_length_m"][i]) == pytest.approx(0.050, rel=2e-3)
        assert float(batch["meta"]["f_number"][i]) == pytest.approx(5.0, rel=2e-3)
        g = torch.Generator().manual_seed(kw.pop("noise_seed"))
        raw = camera(scene, return_intermediates=True, generator=g, **kw).raw
        span = raw.white_level - raw.black_level
        nf = (raw.noise_free - raw.black_level) / span
        torch.testing.assert_close(nf, batch["noise_free_raw"][i:i + 1], rtol=1e-5, atol=1e-6)
        assert float((((raw.data - raw.black_level) / span) != batch["raw"][i:i + 1]).double().mean()) < 2e-3
    assert all(bool(torch.isfinite(batch[k]).all()) for k in ("camera_rgb", "xyz", "srgb"))


def test_relative_illumination_shows_centre_to_corner(dataset):
    """A uniform white scene at the item's FOV through the item's camera: the corner pixel's green over the centre
    pixel's is the lens's relative illumination (projected solid angle of the vignetted beam, ray traced by the
    lens analysis at 64 x 64 pupil samples, not the optics' 24) at the corner's field angle (atan of the pixel's
    radius over the EFL), within 3 % (measured 0.907 against 0.914): the ~9 % falloff at 12 deg must show."""
    camera, scene, kw = camera_for(0, 3, dataset.scene_config, dataset.camera_config, cache=dataset._cache)
    kw.pop("noise_seed")
    _, _, h, w = scene.maps.shape
    flat = Scene.from_factors(torch.ones(1, 1, h, w), scene.illuminant_photons[:, None], scene.wavelengths_nm,
                              hfov_deg=float(scene.hfov_deg.reshape(())), distance_m=1.2,
                              illuminant_photons=scene.illuminant_photons)
    raw = camera(flat, return_intermediates=True, generator=torch.Generator().manual_seed(0), **kw).raw
    nf = (raw.noise_free - raw.black_level)[0, 0].double()  # RGGB: G at (0, 1) of each cell
    n = nf.shape[-1]
    centre, corner = float(nf[n // 2, n // 2 + 1]), float(nf[0, 1])
    r_mm = math.hypot(n // 2 - 0.5, n // 2 - 1.5) * PITCH_M * 1e3  # pixel (0, 1) centre from the axis
    lens = camera.optics.analysis
    theta = math.degrees(math.atan(r_mm / float(lens.effective_focal_length_mm)))
    r_c = math.hypot(0.5, 1.5) * PITCH_M * 1e3  # the centre pixel's own small offset
    theta_c = math.degrees(math.atan(r_c / float(lens.effective_focal_length_mm)))
    ri = float(lens.relative_illumination(theta / lens.max_field_deg, 550.0, samples=64)
               / lens.relative_illumination(theta_c / lens.max_field_deg, 550.0, samples=64))
    assert 11.0 < theta < 13.0 and ri < 0.92
    assert corner / centre == pytest.approx(ri, rel=0.03)


def test_shipped_lens_config_is_valid_and_inside_the_lens_field():
    """configs/synth/lens_cooke.yaml validates, and its scene (sensor + margins at one sample per pixel) stays
    inside the Cooke triplet's 20 deg field (LensOptics raises beyond it): corner = atan(pitch x half diagonal /
    EFL)."""
    cfg = load_config(Path(__file__).resolve().parents[2] / "configs" / "synth" / "lens_cooke.yaml")
    assert cfg["camera"]["optics"]["type"] == "lens" and cfg["scene"]["generator"] == "natural"
    cam, sc = cfg["camera"], cfg["scene"]
    half_diag_m = max(cam["pixel_size_m"]) * math.hypot(sc["height"] + 2 * cam["margin_px"],
                                                        sc["width"] + 2 * cam["margin_px"]) / 2
    assert 8.0 < math.degrees(math.atan(half_diag_m / 0.050)) < 20.0


def test_a_lens_focused_near_keeps_one_scene_sample_per_pixel():
    """Focused at 1.2 m the Cooke triplet's image plane moves back: image height per tan(angle) 52.1 mm for its
    50.0 mm focal length. The pairs sized the field of view with the focal length, so the optical image came out
    4.2 % coarser than the pixels (the sensor resampled it); now with the lens's image_distance_m, for the dataset
    and the stream."""
    from isettorch.data import PairStream
    from isettorch.data.config import pair_config

    cam = dict(CAMERA, optics=dict(LENS, focus_distance_m=1.2))
    scene = {"height": 32, "width": 32, "wavelengths_nm": [400.0, 700.0, 50.0]}
    scene_cfg, cam_cfg = pair_config(scene, cam)
    camera, sc, _ = camera_for(0, 1, scene_cfg, cam_cfg)
    assert camera.optics.image_distance_m == pytest.approx(0.052125, rel=1e-4)
    assert float(camera.optical_image(sc).sample_spacing_m.reshape(-1)[0]) == pytest.approx(PITCH_M, rel=1e-6)
    stream = PairStream(1, seed=1, scene=scene, camera=cam, targets=("camera_rgb",), dtype=torch.float64)
    (group,) = stream._draw_part(0, 0)
    oi = group.camera.optical_image(group.scene)
    assert float(oi.sample_spacing_m.reshape(-1)[0]) == pytest.approx(PITCH_M, rel=1e-6)


def test_the_stream_refuses_lens_configs_it_renders_at_one_field_of_view():
    """A drawn lens renders a stream batch at one field of view and one object distance: several pitches, or a
    distance range with object_distance 'scene', failed at the first batch naming scene.hfov_deg."""
    from isettorch.data import PairStream

    scene = {"height": 32, "width": 32, "wavelengths_nm": [400.0, 700.0, 50.0]}
    with pytest.raises(ValueError, match="camera.pixel_size_m: a ray-traced lens"):
        PairStream(2, scene=scene, camera=dict(CAMERA, pixel_size_m=[4e-4, 5e-4]))
    with pytest.raises(ValueError, match="scene.distance_m: a ray-traced lens"):
        PairStream(2, scene=dict(scene, distance_m=[1.0, 3.0]), camera=dict(CAMERA, optics=dict(
            LENS, object_distance="scene")))
    # one item per part renders it alone: taken
    PairStream(2, scene=scene, camera=dict(CAMERA, pixel_size_m=[4e-4, 5e-4]), parts=2)
    PairStream(1, scene=scene, camera=dict(CAMERA, pixel_size_m=[4e-4, 5e-4]))
