"""PairStream with camera modules and its input checks (the 2026 stream audit): the noise metadata is the measured
noise of each kind of sensor, the full well is where the sensor saturates, a module must fit the scene and have
colour channels, a ray-traced lens module has the drawn lens's geometry, objects near the focal length render as in
CameraPairDataset, and bad arguments raise at construction naming the argument."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from isettorch import Camera
from isettorch.data import PairStream
from isettorch.data.camera_pairs import CameraPairDataset
from isettorch.optics import DiffractionLimitedOptics
from isettorch.sensor import Sensor

SMALL = {"height": 32, "width": 32}
# a uniform grey scene under one light: one dead leaf colour, no HDR ramp, second light or shadow, fixed luminance
FLAT = dict(SMALL, layouts={"dead_leaves": 1.0}, palette_size=1, hdr_decades=[0.0, 0.0], two_light_probability=0.0,
            shadow_probability=0.0, mean_luminance_cd_m2=[500.0, 500.0])


def _camera(**sensor) -> Camera:
    kw = dict(rows=32, cols=32, pixel_size_m=2e-6, cfa="RGGB", dark_current_e_per_s=0.0, prnu_sigma_percent=0.0,
              auto_exposure="mean")
    kw.update(sensor)
    return Camera(DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3), Sensor(**kw))


# Three readouts whose signal-independent noise differs in kind (electrons at the pixel; ``ae_target`` puts the mean
# signal at a fraction of the swing, where shot noise and the floor are of one order):
# * volts (no ADC): read 30 e- and DSNU 20 e-, no quantisation, a 0.05 V analog offset (the dimmest channel's
#   mean is 2.6 read-noise sigmas above 0 V in some draws: without the pedestal a pixel clipped at 0 V);
# * DN (10 bits, black level 64; IMX363-like 0.48 V swing, 80 uV/e-: 5.9 e- per DN): read 6 e-, DSNU 2 e-, and the
#   rounding to whole DN (1/12 DN^2);
# * CDS (Farrell et al. 2004's sensor, preset iset2004_cds): read 50 e- sampled twice (reset and signal), DSNU 2 mV
#   (133 e-) cancelled.
SENSORS = {
    "volts": dict(conversion_gain_v_per_e=1e-4, read_noise_v=3e-3, dsnu_sigma_v=2e-3, ae_target=0.2,
                  analog_offset_v=0.05),
    "dn": dict(conversion_gain_v_per_e=8e-5, voltage_swing_v=0.48, adc_bits=10, black_level_dn=64.0,
               read_noise_v=6 * 8e-5, dsnu_sigma_v=2 * 8e-5, ae_target=0.05),
}


def _cds_camera() -> Camera:
    s = Sensor.preset("iset2004_cds", rows=32, cols=32, pixel_size_m=2e-6, cfa="RGGB", auto_exposure="mean",
                      ae_target=0.12, dark_current_e_per_s=0.0)
    return Camera(DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3), s)


@pytest.mark.parametrize("kind", ["volts", "dn", "cds"])
def test_noise_metadata_is_the_measured_noise_of_the_sensor(kind):
    """On flat scenes (every pixel of a CFA channel has one noise-free value x), the variance of raw - noise_free_raw
    over the pixels of four batches of 8 is ``noise_gain x + noise_floor_var`` within 6 % (32768 pixels: the pooled
    sample variance's standard error is about 1.5 %, the per-batch ratios measured 0.95-1.04). Before, the floor
    added 1/12 of a DN step to a volts readout (1/12 of the 1 V swing: 1e3-1e4 x the measured variance), and with
    CDS counted the cancelled DSNU and one read-noise sample (2.4-4 x the measured)."""
    camera = _cds_camera() if kind == "cds" else _camera(**SENSORS[kind])
    stream = PairStream(8, seed=1, scene=FLAT, camera=camera, targets=("noise_free_raw",))
    measured = predicted = 0.0
    for k in range(4):
        batch = stream.batch(k)
        x = batch["noise_free_raw"].double()
        r = batch["raw"].double() - x
        meta = batch["meta"]
        a = meta["noise_gain"].double().view(-1, 1, 1, 1)
        b = meta["noise_floor_var"].double().view(-1, 1, 1, 1)
        black, white = (meta[key].double().view(-1, 1, 1, 1) for key in ("black_level_dn", "white_level_dn"))
        code = batch["raw"].double() * (white - black) + black  # DN, or volts for the analog readouts
        assert bool((code > 0).all()) and bool((batch["raw"] < 1).all())  # nothing clipped at black or white
        measured += float(r.pow(2).sum())
        predicted += float((a * x + b).sum())
        # the floor is a real share of the variance here (so a wrong floor shows)
        assert float((b / (a * x + b)).mean()) > {"volts": 0.3, "dn": 0.1, "cds": 0.35}[kind]
    assert measured / predicted == pytest.approx(1.0, abs=0.06)
    if kind == "cds":  # the volts readout of a 1 V swing at unit gain: b = 2 x read_v^2 = 2 (50 x 15 uV)^2 V^2
        want = torch.full((8,), 2 * (50 * 15e-6) ** 2, dtype=torch.float64)
        torch.testing.assert_close(meta["noise_floor_var"].double(), want, rtol=1e-6, atol=0)
    # the coefficients from the sensor's parameters (Foi et al. 2008 in normalised units, unit gain): volts, a 1 V
    # swing above a 0.05 V offset, span 0.95 V: a = cg / span, b = (read^2 + DSNU^2) / span^2; DN,
    # K = cg / (swing / 2^10) DN per electron over span = 1023 - 64 DN: a = K / span,
    # b = (K^2 (6^2 + 2^2) e^2 + 1/12 DN^2) / span^2
    k_dn = 8e-5 / (0.48 / 1024)
    want_ab = {"volts": (1e-4 / 0.95, (3e-3**2 + 2e-3**2) / 0.95**2),
               "dn": (k_dn / 959, (k_dn**2 * 40 + 1 / 12) / 959**2)}.get(kind)
    if want_ab is not None:
        torch.testing.assert_close(meta["analog_gain"].double(), torch.ones(8, dtype=torch.float64))
        for key, want in zip(("noise_gain", "noise_floor_var"), want_ab, strict=True):
            torch.testing.assert_close(meta[key].double(), torch.full((8,), want, dtype=torch.float64), rtol=1e-6,
                                       atol=0)


def test_full_well_is_where_the_sensor_saturates():
    """``meta['full_well_e']`` is the sensor's: the IMX363-like preset's 6000 e- (0.48 V swing / 80 uV/e-, the
    published full well of that pixel class), the IMX174 datasheet's saturation capacity 32 000 e- (the photodiode
    clip below its 1 V / cg = 33 684 e- swing); a drawn camera's is its drawn full well, as in CameraPairDataset.
    Before, 1 / conversion gain: 12 500 and 33 684."""
    for preset, full_well in (("imx363", 6000.0), ("imx174_emva", 32000.0)):
        sensor = Sensor.preset(preset, rows=32, cols=32, cfa="RGGB", auto_exposure="percentile")
        camera = Camera(DiffractionLimitedOptics(f_number=4.0, focal_length_m=4e-3), sensor)
        meta = PairStream(2, scene=SMALL, camera=camera, targets=()).batch(0)["meta"]
        torch.testing.assert_close(meta["full_well_e"].double(), torch.full((2,), full_well, dtype=torch.float64),
                                   rtol=1e-6, atol=0)
    drawn = {"full_well_e": [7000.0, 7000.0]}
    assert PairStream(2, scene=SMALL, camera=drawn, targets=()).batch(0)["meta"]["full_well_e"].tolist() == [7000.0] * 2
    assert CameraPairDataset(1, scene=SMALL, camera=drawn, targets=())[0]["meta"]["full_well_e"].item() == 7000.0


def test_a_mono_camera_is_refused_as_by_the_dataset():
    """A monochrome sensor has no white balance or colour targets (relative to the second channel): the stream
    refuses it at construction naming ``camera`` and those targets, as CameraPairDataset refuses a non-Bayer CFA.
    Before: an IndexError at batch(), or meta['white_camera_rgb'] of shape (B, 0) with only noise_free_raw."""
    mono = _camera(cfa="MONO", adc_bits=10)
    for targets in (("noise_free_raw",), ("camera_rgb", "srgb")):
        with pytest.raises(ValueError, match=r"camera: .*monochrome.*camera_rgb, xyz, linear_srgb and srgb"):
            PairStream(2, scene=SMALL, camera=mono, targets=targets)
    with pytest.raises(ValueError, match="camera.cfa_patterns"):
        CameraPairDataset(1, scene=SMALL, camera={"cfa_patterns": ["MONO"]})


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error without CUDA")
def test_device_is_checked_at_construction():
    """A device this machine cannot compute on raises at construction naming ``device`` (the shared check of the
    demosaic benchmark), not a torch error at batch()."""
    from isettorch._checks import check_device
    from isettorch.isp import evaluation

    assert evaluation.check_device is check_device  # one check, importable from both
    for device, message in (("cuda", "CUDA is not available"), (0, "0"),
                            ("meta", "'meta' holds no values"), ("gpu", "'gpu' is not a torch device"),
                            (None, "None is not a torch device")):
        with pytest.raises(ValueError, match=f"device: .*{message}"):
            PairStream(2, scene=SMALL, device=device)
    assert PairStream(2, scene=SMALL, device=torch.device("cpu")).device == torch.device("cpu")


def test_a_camera_module_has_the_scenes_size():
    """A batch is ``scene.height x scene.width`` (as CameraPairDataset's): a module whose sensor is another fixed
    size is refused naming ``camera`` and the scene size (before: 64 x 64 with a black border); one sized to each
    optical image (rows None, every shipped camera YAML; before: 48 x 48 with the margin) renders through a view
    sized to the scene, equal to the same camera built at the scene's size, and its parameters get the gradients."""
    for rows, cols in ((64, 64), (None, 32)):
        with pytest.raises(ValueError, match=r"camera: its sensor is .*scene.height x scene.width is 32x32.*rows=32"):
            PairStream(2, scene=SMALL, camera=_camera(rows=rows, cols=cols))
    fixed = PairStream(2, scene=SMALL, camera=_camera(), targets=("camera_rgb",)).batch(0)
    assert fixed["raw"].shape == (2, 1, 32, 32) and fixed["camera_rgb"].shape == (2, 3, 32, 32)
    free = _camera(rows=None, cols=None)
    batch = PairStream(2, scene=SMALL, camera=free, targets=("camera_rgb",)).batch(0)
    assert free.sensor.rows is None and free.sensor.cols is None  # the user's module is not resized
    for key in ("raw", "camera_rgb"):
        assert torch.equal(batch[key], fixed[key]), key
    free.optics.f_number.requires_grad_(True)
    graph = PairStream(2, scene=SMALL, camera=free, targets=("camera_rgb",), grad=True).batch(0)
    graph["camera_rgb"].sum().backward()
    assert free.optics.f_number.grad is not None and torch.isfinite(free.optics.f_number.grad).all()


def test_a_lens_module_images_at_its_focal_length_as_a_drawn_lens():
    """A ray-traced lens given as a module gets the scene field of view of the drawn ``optics: {type: lens}`` path
    (the lens images at its image_distance_m, its focal length when focused at infinity): its optical image has one
    sample per pixel. Before, the thin-lens image distance at the scene distance: 0.958 x the pitch here (1.917 um
    for 2 um pixels in the audit)."""
    pytest.importorskip("opticalglass")
    lens = {"type": "lens", "lens": "cooke_triplet", "components": 2, "field_samples": 3, "azimuth_samples": 4,
            "pupil_samples": 16, "max_pupil_samples": 64, "ri_samples": 16, "distortion_samples": 4}
    pitch = 5e-4  # 16 + 2 x 8 px of 0.5 mm: scene corners inside the Cooke triplet's 20 deg field
    scene = {"height": 16, "width": 16, "wavelengths_nm": [450.0, 650.0, 100.0]}
    camera = Camera.from_config({"optics": lens, "sensor": {"rows": 16, "cols": 16, "pixel_size_m": pitch,
                                                            "cfa": "RGGB", "adc_bits": 10}})
    (grp,) = PairStream(2, scene=scene, camera=camera, targets=()).draw(0)
    oi = grp.camera.optical_image(grp.scene)
    torch.testing.assert_close(oi.sample_spacing_m.double(), torch.full((2,), pitch, dtype=torch.float64),
                               rtol=1e-6, atol=0)
    (drawn,) = PairStream(2, scene=scene, camera={"optics": lens, "pixel_size_m": [pitch]}, targets=()).draw(0)
    assert torch.equal(grp.scene.hfov_deg, drawn.scene.hfov_deg)


def test_objects_near_the_focal_length_render_as_in_the_dataset():
    """An object 4.1 mm from the 4 mm lens (image distance 164 mm, where 1/f - 1/d cancels in float32): the stream
    renders, as CameraPairDataset does, every item's optical image with one sample per pixel (the field of view is
    computed as the optics compute the geometry). Before: the sensor's internal 'optical-image spacing' error."""
    scene = dict(SMALL, distance_m=0.0041)
    stream = PairStream(3, seed=0, scene=scene, targets=("camera_rgb",))
    batch = stream.batch(0)
    assert bool(torch.isfinite(batch["camera_rgb"]).all()) and float(batch["camera_rgb"].mean()) > 0
    for grp in stream.draw(0):
        pitch = grp.kwargs["pixel_size_m"]
        oi = grp.camera.optical_image(grp.scene, pixel_size_m=pitch)
        torch.testing.assert_close(oi.sample_spacing_m.double(), pitch.double(), rtol=5e-7, atol=0)
    assert bool(torch.isfinite(CameraPairDataset(2, scene=scene, targets=("camera_rgb",)).get_batch([0, 1])
                               ["camera_rgb"]).all())
    with pytest.raises(ValueError, match="scene.distance_m"):
        PairStream(2, scene=dict(SMALL, distance_m=0.004)).batch(0)


def test_arguments_are_checked_at_construction():
    """Each bad argument raises a ValueError naming it; NumPy integers are integers (the same batches)."""
    bad = {"grad": dict(grad="no"), "rank": dict(rank=1.5, world_size=2), "world_size": dict(rank=0, world_size=0)}
    bad["targets"] = dict(targets=None)
    for name, kw in bad.items():
        with pytest.raises(ValueError, match=f"{name}:"):
            PairStream(2, scene=SMALL, **kw)
    with pytest.raises(ValueError, match="rank:"):
        PairStream(2, scene=SMALL, rank=True, world_size=2)
    with pytest.raises(ValueError, match="targets:"):
        PairStream(2, scene=SMALL, targets=3)
    with pytest.raises(ValueError, match="targets:"):
        CameraPairDataset(2, scene=SMALL, targets=None)
    sensor = Sensor(rows=32, cols=32, pixel_size_m=2e-6, cfa="RGGB")
    for module in (sensor, torch.nn.Linear(2, 2)):
        with pytest.raises(ValueError, match=r"camera: expected None, .*Camera module, got a (Sensor|Linear)"):
            PairStream(2, scene=SMALL, camera=module)
    # NumPy integers: batch_size, seed and k alike
    ref = PairStream(2, seed=4, scene=SMALL, targets=()).batch(1)
    got = PairStream(np.int64(2), seed=np.int64(4), scene=SMALL, targets=()).batch(np.int64(1))
    assert torch.equal(got["raw"], ref["raw"]) and got["meta"]["index"].tolist() == [2, 3]


def test_batch_index_and_seed_are_bounded():
    """``k`` stays within what meta['index'] (int64) holds: batch 2^62 - 1 of a 2-item stream holds items up to
    2^63 - 1, batch 2^62 (which would wrap to negative indices: 2^59 gave -2^63 at batch size 16) raises naming
    ``k``. Seeds are 64-bit words: outside [0, 2^64) they would repeat another seed's items (2^64 was seed 0, -1 was
    2^64 - 1); the stream and the dataset refuse them naming ``seed``."""
    stream = PairStream(2, scene={"height": 16, "width": 16}, targets=())
    last = 2 ** 62 - 1
    assert stream.max_batch_index == last
    assert stream.batch(last)["meta"]["index"].tolist() == [2 ** 63 - 2, 2 ** 63 - 1]
    for k in (2 ** 62, 2 ** 70, -1, 1.0, True):
        with pytest.raises(ValueError, match="k:"):
            stream.batch(k)
    with pytest.raises(ValueError, match="k:"):
        stream.draw(2 ** 62)
    with pytest.raises(ValueError, match="start:"):
        PairStream(2, scene=SMALL, rank=1, world_size=2).batches(2 ** 61)
    for seed in (2 ** 64, -1, 2 ** 64 + 5):
        with pytest.raises(ValueError, match="seed:"):
            PairStream(2, seed=seed, scene=SMALL)
        with pytest.raises(ValueError, match="seed:"):
            CameraPairDataset(2, seed=seed, scene=SMALL)
    assert PairStream(2, seed=2 ** 64 - 1, scene=SMALL).seed == 2 ** 64 - 1
    assert CameraPairDataset(2, seed=2 ** 64 - 1, scene=SMALL).seed == 2 ** 64 - 1


def test_colour_targets_follow_the_cameras_response_before_its_pixel_optics(monkeypatch):
    """A grey scene (every surface 0.4) under one daylight through a camera whose microlenses follow the physical
    convention (the whole pixel's light meets the etendue) with a half-size photodiode: at every pixel the XYZ
    target's Y is the normalised green camera value divided by that pixel's etendue (0.76 here, on axis and off: it
    holds the photodiode's share), so the targets' white is the camera's response before its pixel optics. The
    targets scaled XYZ by the photodiode's area while the camera used the pixel's (Sensor.collecting_area_m2 is
    now the one rule): Y was fill x that, 0.38 of the camera's green."""
    from pathlib import Path

    import isettorch
    import isettorch.data.batched as batched
    from isettorch.camera import load_yaml

    cfg = load_yaml((Path(isettorch.__file__).parent / "configs/cameras/phone_microlens.yaml").read_text())
    cfg["sensor"]["pixel_optics"]["diffraction"] = False  # one etendue per pixel (not per wavelength)
    cfg["sensor"]["fill_factor"] = 0.5
    cam = Camera.from_config(cfg)
    assert cam.sensor.pixel_optics.convention == "physical"
    monkeypatch.setattr(batched, "_reflectances", lambda nb, k, wl, g, *a, **kw: torch.full(
        (nb, k, len(wl)), 0.4, dtype=torch.float64, device=wl.device))
    stream = PairStream(1, scene={"height": 32, "width": 32, "illuminants": {"daylight": 1.0},
                                  "two_light_probability": 0.0, "shadow_probability": 0.0, "hdr_decades": [0.0, 0.0]},
                        camera=cam, dtype=torch.float64, targets=("camera_rgb", "xyz"))
    batch = stream.batch(0)
    group = stream.draw(0)[0]
    etendue = group.camera.sensor.etendue_map(group.camera.optical_image(group.scene))[0]
    assert float(etendue.max()) < 0.8  # the etendue holds the photodiode's share (0.5) of the pixel's light
    green, y = batch["camera_rgb"][0, 1], batch["xyz"][0, 1]
    assert float(green.max()) < 0.99  # unclipped
    torch.testing.assert_close(y * etendue / green, torch.ones_like(y), rtol=0, atol=1e-3)


def test_a_camera_sized_to_the_scene_is_rendered_as_it_is_at_each_batch():
    """A camera whose sensor is sized to the optical image (rows / cols None, as every shipped camera config) was
    rendered through a view made when the stream was built: the noise switched off, a new analog gain or new optics
    on the user's camera afterwards were ignored, unsaid (a camera with its size set followed them). Now both do,
    and the user's own sensor keeps its size."""
    import warnings

    for sized in (False, True):
        cam = Camera.from_config("imx363")
        if sized:
            cam.sensor.rows, cam.sensor.cols = 32, 32
        stream = PairStream(2, seed=0, scene=SMALL, camera=cam, targets=("noise_free_raw",))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            noisy = stream.batch(0)
            assert float((noisy["raw"] - noisy["noise_free_raw"]).abs().max()) > 0.02
            cam.noise = False  # then the raw is the noise-free one's ADC codes: within half a code of 959
            quiet = stream.batch(0)
            assert float((quiet["raw"] - quiet["noise_free_raw"]).abs().max()) <= 0.5 / 959 + 1e-6, sized
            cam.sensor.analog_gain = 4.0
            assert stream.batch(0)["meta"]["analog_gain"].tolist() == [4.0, 4.0], sized
            cam.optics = DiffractionLimitedOptics(f_number=16.0, focal_length_m=4.38e-3)
            assert stream.batch(0)["meta"]["f_number"].tolist() == [16.0, 16.0], sized
        assert (cam.sensor.rows, cam.sensor.cols) == ((32, 32) if sized else (None, None))


@pytest.mark.parametrize("margin_px", [0, 2])
def test_a_small_margin_does_not_wrap_the_blur_around(margin_px):
    """The pairs' optics buffer their FFT by twice the margin (edge-continued); at margin_px 0 that was no buffer,
    the blur circular: a lit left border put 47 % of its level on the raw's right border at f/8 and 1.4 um (the
    diffraction tail there is about 1 %). The buffer is at least 16 samples: the right border's light then falls
    off from the middle's, as at the default margin of 8."""
    from isettorch.scene import Scene

    profiles = {}
    for m in (margin_px, 8):
        stream = PairStream(2, scene=SMALL, camera={"margin_px": m, "f_number": [8.0], "pixel_size_m": [1.4e-6]})
        grp = stream.draw(0)[0]
        n = 32 + 2 * m
        maps = torch.zeros(2, 1, n, n, dtype=grp.scene.dtype)
        maps[..., :, :m + 4] = 1.0  # the sensor's first 4 columns lit
        spectra = torch.full((2, 1, grp.scene.wavelengths_nm.numel()), 1e16, dtype=grp.scene.dtype)
        scene = Scene.from_factors(maps, spectra, grp.scene.wavelengths_nm, hfov_deg=grp.scene.hfov_deg,
                                   distance_m=grp.scene.distance_m, validate=False)
        raw = grp.camera(scene, return_intermediates=True, noise=False, **grp.kwargs).raw
        prof = (raw.noise_free[0, 0].double() - float(raw.black_level)).mean(0)
        profiles[m] = prof / prof[1]
    assert float(profiles[margin_px][-1]) < float(profiles[margin_px][16]) < 0.05
    np.testing.assert_allclose(profiles[margin_px][8:].numpy(), profiles[8][8:].numpy(), atol=5e-3)


def test_an_items_cfa_does_not_depend_on_its_position_in_the_batch():
    """A part's items were placed in the order of their drawn CFAs: position i held the i-th order statistic, so a
    batch's first item was always the first CFA and consecutive slices of a batch (what a trainer hands out) saw
    one CFA each. Each group's outputs now go to its camera draws' positions: over 20 batches of 8 the first item
    takes every CFA, a batch of 64 is no longer sorted, and each group still renders its items as its camera does."""
    cams = {"cfa_patterns": ["RGGB", "GRBG", "GBRG", "BGGR"]}
    stream = PairStream(8, seed=0, scene={"height": 16, "width": 16}, camera=cams, targets=("noise_free_raw",),
                        parts=1)

    def codes(batch):
        return (batch["meta"]["cfa"].reshape(batch["meta"]["cfa"].shape[0], 4) == 0).float().argmax(1)

    first = {int(codes(stream.batch(k))[0]) for k in range(20)}
    assert first == {0, 1, 2, 3}  # (before: {0})
    big = codes(PairStream(64, seed=0, scene={"height": 16, "width": 16}, camera=cams, targets=("camera_rgb",),
                           parts=1).batch(0))
    assert bool((big[1:] < big[:-1]).any())
    batch = stream.batch(3)
    assert batch["meta"]["index"].tolist() == list(range(24, 32))
    for grp in stream.draw(3):  # the group's own camera on its scenes gives the items at the group's positions
        raw = grp.camera(grp.scene, return_intermediates=True, **grp.kwargs).raw
        black, white = raw.levels()
        torch.testing.assert_close((raw.noise_free - black) / (white - black), batch["noise_free_raw"][grp.index],
                                   rtol=2e-5, atol=2e-6)
        assert len(set(codes(batch)[grp.index].tolist())) == 1
