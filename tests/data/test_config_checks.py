"""The training-data config (`merge_config`, `pair_config`): one validation for `isettorch synth`, `PairStream` and
`CameraPairDataset`; a bad value raises one ValueError naming its dotted key, nothing is truncated or ignored."""

import math
import re
from pathlib import Path

import pytest
import torch

from isettorch.cli import main
from isettorch.data import PairStream
from isettorch.data.camera_pairs import CameraPairDataset, camera_for
from isettorch.data.config import (
    SCENE_DEFAULTS,
    SYNTH_DEFAULTS,
    WAVELENGTH_RANGE_NM,
    load_config,
    merge_config,
    natural_config,
)
from isettorch.data.scenes import SyntheticSceneDataset, generate_scene
from isettorch.data.writer import write_dataset

REPO = Path(__file__).resolve().parents[2]
SMALL = {"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 50.0]}
CAM = {"f_number": [2.8], "pixel_size_m": [2.0e-6]}


def _pair_errors(scene: dict | None, camera: dict | None) -> list[str]:
    """The messages of synth's config check, CameraPairDataset and PairStream for one config (one validation)."""
    messages = []
    for make in (lambda: merge_config({"scene": scene or {}, "camera": camera or {}}),
                 lambda: CameraPairDataset(2, 0, scene, camera),
                 lambda: PairStream(2, 0, scene, camera)):
        with pytest.raises(ValueError) as err:
            make()
        messages.append(str(err.value))
    return messages


# --- scene.hfov_deg: the camera pairs' field of view follows the sensor ------------------------------------------
@pytest.mark.parametrize("hfov", [[0.0, 0.0], [170.0, 200.0], [10.0, 12.0], 15.0])
def test_pairs_reject_a_field_of_view_they_would_ignore(hfov):
    for msg in _pair_errors({**SMALL, "hfov_deg": hfov}, CAM):
        assert msg.startswith("scene.hfov_deg: camera pairs take the scene's field of view from the sensor")
        assert "remove it" in msg


@pytest.mark.parametrize("scene, key", [
    ({"generator": "natural", "illuminants": {"led": 1.0}}, "scene.illuminants: the natural generator does not "),
    ({"generator": "natural", "hdr_decades": [3.0, 3.0]}, "scene.hdr_decades: the natural generator does not "),
    ({"generator": "natural", "palette_size": 3}, "scene.palette_size: the natural generator does not "),
    ({"natural": {"components": {"grain": {"probability": 1.0}}}}, "scene.natural: options of the natural generator"),
])
def test_a_key_the_scene_generator_does_not_read_is_refused(scene, key):
    """The layouts generator's keys with the natural generator (LED lights, 3 decades of HDR, a palette of 3) and
    natural options with the layouts generator were accepted and changed nothing (a batch equal to the default
    config's); refused like hfov_deg, by synth's check, the dataset and the stream alike."""
    for msg in _pair_errors({**SMALL, **scene}, CAM):
        assert msg.startswith(key), msg
    ok = merge_config({"scene": {**SMALL, "generator": "natural", "natural": {"components": {"grain": {
        "probability": 1.0}}}}})  # (what each generator reads is accepted)
    assert ok["scene"]["natural"]["components"]["grain"]["probability"] == 1.0


def test_pairs_accept_the_default_field_of_view_as_the_shipped_config_sets_it():
    """configs/synth/default.yaml spells out the default ``hfov_deg`` (commented "ignored by camera pairs"): it loads,
    and an item with it is bitwise the item without it."""
    assert load_config(REPO / "configs/synth/default.yaml")["scene"]["hfov_deg"] == SCENE_DEFAULTS["hfov_deg"]
    a = CameraPairDataset(2, 1, {**SMALL, "hfov_deg": [4.0, 20.0]}, CAM)[1]
    b = CameraPairDataset(2, 1, SMALL, CAM)[1]
    assert torch.equal(a["raw"], b["raw"]) and torch.equal(a["camera_rgb"], b["camera_rgb"])


def test_scene_dataset_honours_and_checks_hfov():
    """Outside camera pairs the key is drawn (SyntheticSceneDataset), so it must be a field of view in (0, 180)."""
    ds = SyntheticSceneDataset(2, seed=0, config={"height": 16, "width": 16, "hfov_deg": [30.0, 30.0]})
    assert float(ds[0].hfov_deg) == 30.0
    for bad in ([0.0, 0.0], [170.0, 200.0], [20.0, 10.0], []):
        with pytest.raises(ValueError, match=r"^scene\.hfov_deg: expected a range \[lo, hi\].*\(0, 180\)"):
            merge_config({"hfov_deg": bad}, SCENE_DEFAULTS, "scene")


def test_scene_dataset_rejects_the_natural_generator_it_would_ignore():
    with pytest.raises(ValueError, match="^scene.generator: generate_scene and SyntheticSceneDataset draw"):
        SyntheticSceneDataset(2, config={"generator": "natural"})
    with pytest.raises(ValueError, match="^scene.generator"):
        generate_scene(0, 0, {"generator": "natural", "height": 16, "width": 16})


# --- integers: never truncated -------------------------------------------------------------------------------------
def test_integers_are_not_truncated():
    for msg in _pair_errors(SMALL, {**CAM, "bits": 12.5}):
        assert msg == "camera.bits: expected an integer, got 12.5"
    for msg in _pair_errors({**SMALL, "height": 16.5}, CAM):
        assert msg == "scene.height: expected an integer, got 16.5"
    # an integral float is that integer (YAML 12.0), as before
    assert merge_config({"camera": {"bits": 10.0}})["camera"]["bits"] == 10
    assert isinstance(merge_config({"camera": {"bits": 10.0}})["camera"]["bits"], int)
    for bad in (1.7, True, "1"):
        for make in (PairStream, CameraPairDataset, SyntheticSceneDataset):
            with pytest.raises(ValueError, match=f"^seed: expected an integer, got {bad!r}$"):
                make(2, seed=bad)
    with pytest.raises(ValueError, match="^length: expected a non-negative integer, got 2.5"):
        CameraPairDataset(2.5)
    with pytest.raises(ValueError, match="^seed: expected an integer, got 1.5"):
        merge_config({"seed": 1.5})
    assert PairStream(2, seed=7).seed == 7


# --- ranges, in merge_config, naming the key -------------------------------------------------------------------------
BAD = [  # (section, key, value, start of the message)
    ("camera", "peak_qe", [0.5, 2.0], "camera.peak_qe: expected a range [lo, hi] of two finite numbers with lo <= hi, "
                                      "both in (0, 1]"),
    ("camera", "peak_qe", [0.0, 0.5], "camera.peak_qe: expected a range"),
    ("camera", "qe_variation", -1.0, "camera.qe_variation: expected a shift scale (x 10 nm per channel) in [0, 10], "
                                     "got -1.0"),
    ("camera", "qe_variation", math.nan, "camera.qe_variation: expected a shift scale"),
    ("camera", "qe_variation", [0.0, 1.0], "camera.qe_variation: expected a number"),
    ("camera", "qe_variation", 100.0, "camera.qe_variation: expected a shift scale"),  # (a channel's QE was 0)
    ("camera", "bits", 0, "camera.bits: expected an integer number of ADC bits in [1, 32], got 0"),
    ("camera", "bits", 40, "camera.bits: expected an integer number of ADC bits in [1, 32], got 40"),
    ("camera", "black_level_dn", 5000.0, "camera.black_level_dn: expected a black level in DN (camera.bits = 12: "
                                         "below 2^12 - 1) in [0, 4095), got 5000.0"),
    ("camera", "black_level_dn", -1.0, "camera.black_level_dn: expected a black level"),
    ("camera", "fill_factor", 0.0, "camera.fill_factor: expected a fraction in (0, 1], got 0.0"),
    ("camera", "fill_factor", 1.5, "camera.fill_factor: expected a fraction in (0, 1], got 1.5"),
    ("camera", "focal_length_m", -4e-3, "camera.focal_length_m: expected a number > 0"),
    ("camera", "pixel_size_m", [-1e-6], "camera.pixel_size_m: expected a non-empty list of finite numbers > 0"),
    ("camera", "f_number", [], "camera.f_number: expected a non-empty list of finite numbers >= 0.5 (one drawn per "
                               "item; 0.5: the fastest lens in air, N = 1 / (2 NA)), got []"),
    ("camera", "f_number", [0.0, 2.8], "camera.f_number: expected a non-empty list of finite numbers >= 0.5"),
    # the optics' own bound, named with its config key (the message named a bare 'f_number' at the first batch)
    ("camera", "f_number", [0.1], "camera.f_number: expected a non-empty list of finite numbers >= 0.5"),
    ("camera", "full_well_e", [0.0, 0.0], "camera.full_well_e: expected a range [lo, hi] of two finite numbers with "
                                          "lo <= hi, both > 0, got [0.0, 0.0]"),
    ("camera", "full_well_e", [], "camera.full_well_e: expected a range [lo, hi]"),
    ("camera", "full_well_e", [9000.0, 6000.0], "camera.full_well_e: expected a range [lo, hi]"),
    ("camera", "analog_gain", [0.0, 4.0], "camera.analog_gain: expected a range [lo, hi]"),
    ("camera", "read_noise_e", [-1.0, 2.0], "camera.read_noise_e: expected a range [lo, hi] of two finite numbers "
                                            "with lo <= hi, both >= 0"),
    ("camera", "prnu_sigma_percent", [1.0], "camera.prnu_sigma_percent: expected a range [lo, hi]"),
    ("camera", "dark_current_e_per_s", [0.0, 20.0], "camera.dark_current_e_per_s: drawn log-uniformly, so a range "
                                                    "[lo, hi] needs lo > 0"),
    ("camera", "exposure_ev", [math.nan, 1.0], "camera.exposure_ev: expected a range [lo, hi]"),
    ("camera", "margin_px", -3, "camera.margin_px: expected an integer number of pixels >= 0, got -3"),
    ("camera", "margin_px", 2.5, "camera.margin_px: expected an integer, got 2.5"),
    ("scene", "height", 0, "scene.height: expected an integer number of pixels >= 2, got 0"),
    ("scene", "width", 17, "scene.height/width: expected even sizes (whole Bayer cells), got 16x17"),
    ("scene", "palette_size", 0, "scene.palette_size: expected an integer number of colours >= 1, got 0"),
    ("scene", "two_light_probability", 2.0, "scene.two_light_probability: expected a probability in [0, 1], got 2.0"),
    ("scene", "shadow_probability", -0.1, "scene.shadow_probability: expected a probability in [0, 1]"),
    ("scene", "pca_fraction", 3.0, "scene.pca_fraction: expected a probability in [0, 1], got 3.0"),
    ("scene", "pca_fraction", [0.2, 0.8], "scene.pca_fraction: expected a number"),
    ("scene", "distance_m", 0.0, "scene.distance_m: expected a number > 0, got 0.0"),
    ("scene", "distance_m", [0.0, 2.0], "scene.distance_m: expected a range [lo, hi] of two finite numbers with "
                                        "lo <= hi, both > 0"),
    # a thin lens images nothing nearer than its focal length: a range reaching below it failed at its first such
    # draw (after 53 shards of a synth run, and again on every rerun)
    ("scene", "distance_m", [0.001, 1.2], "scene.distance_m: expected object distances beyond camera.focal_length_m "
                                          "(0.004 m), got [0.001, 1.2]"),
    ("scene", "distance_m", 0.003, "scene.distance_m: expected object distances beyond camera.focal_length_m"),
    ("scene", "mean_luminance_cd_m2", [0.0, 100.0], "scene.mean_luminance_cd_m2: expected a range [lo, hi]"),
    # float32 overflowed from 1e22 cd/m2 with an error naming the sensor's electron_rate; a 1 K blackbody gave 0 / 0
    ("scene", "mean_luminance_cd_m2", [1e22, 1e22], "scene.mean_luminance_cd_m2: expected a range [lo, hi] of two "
                                                    "finite numbers with lo <= hi, both in [1e-20, 1e+12]"),
    ("scene", "hdr_decades", [0.0, 40.0], "scene.hdr_decades: expected a range [lo, hi] of two finite numbers with "
                                          "lo <= hi, both in [0, 12]"),
    ("scene", "cct_range_k", {"blackbody": [1.0, 1.0]}, "scene.cct_range_k.blackbody: expected a range [lo, hi] "
                                                        "of two finite numbers with lo <= hi, both >= 100"),
    ("scene", "shadow_ambient", [0.0, 0.3], "scene.shadow_ambient: drawn log-uniformly"),
    ("scene", "hdr_decades", [-1.0, 1.0], "scene.hdr_decades: expected a range [lo, hi]"),
    ("scene", "wavelengths_nm", [100.0, 2000.0, 10.0], "scene.wavelengths_nm: expected [start, stop, step] with "
                                                       "400 <= start <= stop <= 700 nm"),
    ("scene", "wavelengths_nm", [400.0, 700.0, -10.0], "scene.wavelengths_nm: expected [start, stop, step]"),
    ("scene", "wavelengths_nm", [400.0, 700.0, 7.0], "scene.wavelengths_nm: expected stop - start to be a whole "
                                                     "number of steps"),
    ("scene", "cct_range_k", {"daylight": [3000.0, 5000.0]}, "scene.cct_range_k.daylight: expected a range [lo, hi] "
                                                             "of two finite numbers with lo <= hi, both in [4000, "
                                                             "25000]"),
    ("scene", "cct_range_k", {"blackbody": [0.0, 5000.0]}, "scene.cct_range_k.blackbody: expected a range"),
    ("scene", "layouts", {"edges": math.nan}, "scene.layouts: expected non-negative weights with a positive sum"),
    ("scene", "natural", {"components": {"fine_detail": {"probability": 1.5}}},
     "scene.natural: config: 'components.fine_detail.probability': expected a probability in [0, 1], got 1.5"),
    ("scene", "natural", {"components": {"dead_leaves": {"leaves": [1200, 500]}}},
     "scene.natural: config: 'components.dead_leaves.leaves': expected a range [lo, hi] of two integers"),
    # zeros that divided at batch time (ZeroDivisionError, a zero stride), negative sizes and the exponent 1 of the
    # leaf radii's inverse CDF
    ("scene", "natural", {"components": {"dead_leaves": {"r_min_px": 0.0}}},
     "scene.natural: config: 'components.dead_leaves.r_min_px': expected a number > 0, got 0.0"),
    ("scene", "natural", {"components": {"dead_leaves": {"brightness": [0.0, 0.0]}}},
     "scene.natural: config: 'components.dead_leaves.brightness': expected a range [lo, hi] of two finite numbers "
     "with 0 < lo <= hi"),
    ("scene", "natural", {"components": {"fine_detail": {"supersample": 0}}},
     "scene.natural: config: 'components.fine_detail.supersample': expected an integer >= 1, got 0"),
    ("scene", "natural", {"components": {"dead_leaves": {"exponent": 1.0}}},
     "scene.natural: config: 'components.dead_leaves.exponent': expected an exponent other than 1"),
    ("scene", "natural", {"components": {"illuminant": {"kinds": {"daylight": 1.0, "blackbdy": 3.0}}}},
     "scene.natural: config: 'components.illuminant.kinds': 'blackbdy': unknown kind; expected some of"),
    ("scene", "natural", {"components": {"illuminant": {"kinds": {"candle": 1.0}}}},
     "scene.natural: config: 'components.illuminant.kinds': 'candle': unknown kind"),
    ("scene", "natural", {"components": {"textured_leaves": {"min_size_px": -3}}},
     "scene.natural: config: 'components.textured_leaves.min_size_px': expected an integer >= 0, got -3"),
    # accepted, then refused by the per-item generator without the key's name and drawn anyway by the stream (a
    # stream of 'recovery' materials only, radii below r_min_px)
    ("scene", "natural", {"components": {"palette": {"measured": 0.0, "recovery": 0.0, "random": 0.0}}},
     "scene.natural: config: 'components.palette' expected a positive total of the kind weights"),
    ("scene", "natural", {"components": {"textured_leaves": {"grating_cpp": [0.02, 3.0]}}},
     "scene.natural: config: 'components.textured_leaves.grating_cpp' expected frequencies in (0, 0.5]"),
    # sampled at pixel centres: 0.75 cycles/pixel came out as 0.25, 1 and 2 as a flat field (texture audit)
    ("scene", "natural", {"components": {"textured_leaves": {"grating_cpp": [0.02, 1.0]}}},
     "scene.natural: config: 'components.textured_leaves.grating_cpp' expected frequencies in (0, 0.5]"),
    ("scene", "natural", {"components": {"dead_leaves": {"r_max_fraction": 0.01}}},
     "scene.natural: config: 'components.dead_leaves.r_max_fraction' x size"),
    ("scene", "natural", {"components": {"grain": {"amplitude": [0.0, 0.01]}}},
     "scene.natural: config: 'components.grain.amplitude': expected a range [lo, hi] of two finite numbers with "
     "0 < lo <= hi"),
    ("scene", "natural", {"wavelengths_nm": [400.0, 700.0, 5.0]},
     "scene.natural.wavelengths_nm: the natural scene's wavelengths_nm follows scene.wavelengths_nm; remove it"),
    ("scene", "natural", {"mean_radiance_scale": 2.0},
     "scene.natural.mean_radiance_scale: the natural scene's mean_radiance_scale follows "
     "scene.mean_luminance_cd_m2; remove it"),
]


@pytest.mark.parametrize("section, key, value, message", BAD, ids=[f"{s}.{k}={v!r}" for s, k, v, _ in BAD])
def test_bad_values_are_named_alike_by_synth_dataset_and_stream(section, key, value, message):
    scene, camera = dict(SMALL), dict(CAM)
    (scene if section == "scene" else camera)[key] = value
    for msg in _pair_errors(scene, camera):
        assert msg.startswith(message), msg


def test_the_pair_configs_prnu_bound_is_the_sensors():
    """The pair configs bound PRNU by the literal 20 (the data package does not import the sensor module); it is the
    sensor's MAX_PRNU_SIGMA_PERCENT, so the two cannot drift apart."""
    from isettorch.sensor.sensor import MAX_PRNU_SIGMA_PERCENT

    at_bound = {**CAM, "prnu_sigma_percent": [0.0, MAX_PRNU_SIGMA_PERCENT]}
    merge_config({"scene": dict(SMALL), "camera": at_bound})  # accepted
    PairStream(2, 0, dict(SMALL), at_bound)
    for msg in _pair_errors(dict(SMALL), {**CAM, "prnu_sigma_percent": [0.0, MAX_PRNU_SIGMA_PERCENT + 0.5]}):
        assert msg.startswith("camera.prnu_sigma_percent: expected a range"), msg


def test_the_sections_alone_are_checked_too():
    with pytest.raises(ValueError, match=r"^camera\.full_well_e: expected a range"):
        merge_config({"full_well_e": [0.0, 0.0]}, SYNTH_DEFAULTS["camera"], "camera")
    with pytest.raises(ValueError, match=r"^scene\.palette_size: expected an integer"):
        SyntheticSceneDataset(2, config={"palette_size": 0})
    with pytest.raises(ValueError, match=r"^shard_size: expected an integer number of items >= 1, got 0"):
        merge_config({"shard_size": 0})
    with pytest.raises(ValueError, match=r"^targets: expected names from"):
        merge_config({"targets": ["camera_rgbx"]})
    with pytest.raises(ValueError, match=r"^count: expected a positive integer, got 2.5"):
        write_dataset({}, "unused", 2.5)
    # not truncated: shard=0.5 matched no file and wrote nothing, num_shards=1.5 wrote half of the shards
    for key, value, what in (("shard", 0.5, "a non-negative integer"), ("num_shards", 1.5, "a positive integer"),
                             ("rank", 0.5, "a non-negative integer"), ("world_size", 2.0, "a positive integer"),
                             ("workers", 0.5, "a non-negative integer"), ("rank", "0", "a non-negative integer")):
        with pytest.raises(ValueError, match=rf"^{key}: expected {what}, got {value!r}"):
            write_dataset({}, "unused", 2, **{key: value, **({"world_size": 1} if key == "rank" else {})})
    # a section that is not a mapping is an error, also when it is empty or falsy (it was read as the defaults)
    for bad in ([], 0, False, ""):
        with pytest.raises(ValueError, match=r"^camera: expected a mapping"):
            PairStream(1, camera=bad)
        with pytest.raises(ValueError, match=r"^scene: expected a mapping"):
            PairStream(1, scene=bad)
    with pytest.raises(ValueError, match=r"^config: 'wavelengths_nm': expected \[start, stop, step\]"):
        natural_config({"wavelengths_nm": [380.0, 780.0, 10.0]})


def test_the_wavelength_range_is_what_the_spectra_support():
    """Inside the range every generator gives finite spectra (outside, the reflectance model's draws are NaN)."""
    lo, hi = WAVELENGTH_RANGE_NM
    scene = generate_scene(0, 0, {"height": 16, "width": 16, "wavelengths_nm": [lo, hi, 25.0]})
    assert torch.isfinite(scene.photons).all()
    batch = PairStream(2, 0, {**SMALL, "wavelengths_nm": [lo, hi, 25.0], "generator": "natural"}, CAM).batch(0)
    assert torch.isfinite(batch["srgb"]).all()


def test_valid_edge_values_are_accepted():
    merge_config({"scene": {"two_light_probability": 1.0, "pca_fraction": 0.0, "wavelengths_nm": [550.0, 550.0, 10.0],
                            "shadow_ambient": [0.0, 0.0], "distance_m": [0.5, 2.0], "palette_size": 1,
                            "cct_range_k": {"led": [1000.0, 25000.0]}},
                  "camera": {"peak_qe": [1.0, 1.0], "fill_factor": 1.0, "qe_variation": 0, "bits": 1,
                             "black_level_dn": 0.0, "margin_px": 0, "dark_current_e_per_s": 0.0,
                             "dsnu_sigma_e": [0.0, 0.0], "full_well_e": 5000}, "seed": 2**64 - 1})
    # seeds are 64-bit words (config.seed_for): -3 would repeat seed 2^64 - 3's items, as the datasets refuse it
    with pytest.raises(ValueError, match=r"^seed: expected an integer in \[0, 2\*\*64\)"):
        merge_config({"seed": -3})


def test_synth_cli_prints_one_line_naming_the_key(tmp_path, capsys):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("camera:\n  full_well_e: [0.0, 0.0]\n")
    assert main(["synth", "--config", str(cfg), "--out", str(tmp_path / "o"), "--count", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "camera.full_well_e: expected a range [lo, hi]" in err[0]
    cfg.write_text("scene:\n  hfov_deg: [170, 200]\n")
    assert main(["synth", "--config", str(cfg), "--out", str(tmp_path / "o"), "--count", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "scene.hfov_deg: camera pairs take the scene's field of view from the sensor" in err[0]


# --- noise metadata: the model leaves out PRNU ------------------------------------------------------------------------
def test_noise_metadata_leaves_out_prnu_which_adds_its_square():
    """A flat field through an item's camera: the residual variance is ``noise_gain x + noise_floor_var`` (the
    metadata) plus ``(prnu_sigma_percent / 100 x)^2`` (the fixed pattern the metadata leaves out, as documented)."""
    scene = {"height": 128, "width": 128, "wavelengths_nm": [400.0, 700.0, 100.0]}
    camera = {**CAM, "prnu_sigma_percent": [1.5, 1.5], "full_well_e": [20000.0, 20000.0], "analog_gain": [1.0, 1.0],
              "read_noise_e": [2.0, 2.0], "dsnu_sigma_e": [1.0, 1.0], "dark_current_e_per_s": [1.0, 1.0]}
    ds = CameraPairDataset(1, seed=3, scene=scene, camera=camera, targets=())
    meta = ds[0]["meta"]
    a, b, t = (float(meta[k]) for k in ("noise_gain", "noise_floor_var", "exposure_s"))
    cam, _, kw = camera_for(0, 3, ds.scene_config, ds.camera_config)
    g = torch.Generator().manual_seed(kw.pop("noise_seed"))
    gain = kw.pop("analog_gain")
    kw.pop("exposure_ev"), kw.pop("qe_scale")
    rate = torch.full((1, 1, 128, 128), 0.5 / a / t, dtype=torch.float64)  # x = electrons x noise_gain ~ 0.5
    raw = cam.sensor.capture(rate, exposure_s=torch.tensor([t], dtype=torch.float64), analog_gain=gain, noise=True,
                             generator=g, **kw)
    span = raw.white_level - raw.black_level
    x = (raw.noise_free.double() - raw.black_level) / span
    resid = (raw.data.double() - raw.noise_free.double()) / span
    xm = float(x.mean())
    measured, model = float(resid.var()), a * xm + b
    prnu = (float(meta["prnu_sigma_percent"]) / 100 * xm) ** 2
    assert 0.45 < xm < 0.55 and float(x.max()) < 0.9  # below white: no clipping
    assert measured == pytest.approx(model + prnu, rel=0.06)  # sampling error of 16384 pixels: ~1 %
    assert measured > 2 * model  # without the PRNU term the model falls well short


def test_dataset_indices_are_integers_and_bool_tensors_are_refused():
    # a 0-d integer tensor (a sampler's) is that item; a 0-d bool tensor was item 0 or 1 without a word
    import numpy as np

    from isettorch.data.natural import NaturalSceneDataset

    for ds in (SyntheticSceneDataset(3, seed=1, config={"height": 8, "width": 8}), NaturalSceneDataset(3, seed=1)):
        for bad in (torch.tensor(True), torch.tensor(1 + 0j), torch.tensor(1.0), np.bool_(True)):
            with pytest.raises(TypeError, match=r"^index: expected an integer, got "):
                ds[bad]
        with pytest.raises(IndexError, match=r"^index: expected 0 <= index < 3, got 3$"):
            ds[torch.tensor(3)]
    ds = SyntheticSceneDataset(3, seed=1, config={"height": 8, "width": 8})
    assert torch.equal(ds[torch.tensor(2)].photons, ds[2].photons)
    assert torch.equal(ds[torch.tensor(-1, dtype=torch.int8)].photons, ds[2].photons)


def test_whole_numbers_for_float_keys_are_the_same_config():
    """``black_level_dn: 64`` is the default 64.0, and a range of ints the same range of floats: an int hashed apart
    (writer.config_hash), so a resumed or second-rank write of the same items was refused as another config."""
    from isettorch.data import writer
    from isettorch.data.config import SYNTH_DEFAULTS, merge_config

    base = merge_config({})
    same = merge_config({"camera": {"black_level_dn": 64,
                                    "full_well_e": [int(v) for v in SYNTH_DEFAULTS["camera"]["full_well_e"]]}})
    assert same == base and writer.config_hash(same, 4) == writer.config_hash(base, 4)
    assert isinstance(same["camera"]["black_level_dn"], float)
    ints, floats = merge_config({"scene": {"distance_m": [1, 5]}}), merge_config({"scene": {"distance_m": [1.0, 5.0]}})
    assert writer.config_hash(ints, 4) == writer.config_hash(floats, 4)
    other = merge_config({"camera": {"black_level_dn": 65}})
    assert writer.config_hash(other, 4) != writer.config_hash(base, 4)


def test_tiny_sensors_a_pair_config_accepts_render_and_indices_are_integers():
    """A 4 x 4 sensor (a 20 x 20 scene with the default margin) passed pair_config and rendered in the stream, but
    CameraPairDataset re-checked the sensor's size alone and refused it ("at least 5 pixels ... got 4x4");
    render_pair(s) rounded 1.7 to item 1 and read '0' and True as items."""
    import torch

    from isettorch.data.camera_pairs import CameraPairDataset, render_pair, render_pairs
    from isettorch.data.config import pair_config

    for scene, camera in (({"height": 4, "width": 4}, {}), ({"height": 2, "width": 2}, {"margin_px": 2})):
        pair_config(scene, camera)
        item = CameraPairDataset(1, seed=0, scene=scene, camera=camera)[0]
        assert item["raw"].shape[-2:] == (scene["height"], scene["width"]) and bool(torch.isfinite(item["raw"]).all())
    s, c = pair_config({"height": 8, "width": 8}, {})
    for bad in (1.7, "0", True):
        with pytest.raises((ValueError, TypeError), match="indices"):
            render_pairs([0, bad], 0, s, c)
        with pytest.raises((ValueError, TypeError), match="index"):
            render_pair(bad, 0, s, c)


def test_natural_values_equal_to_a_default_but_of_another_type_are_checked():
    """``True == 1 == 1.0`` and ``[2.0, 8.0] == [2, 8]``: a value equal to its default was skipped unchecked, so
    ``enabled: 1``, ``probability: false`` and float ``materials`` passed (``enabled: 0`` was refused). Whole numbers
    for float keys still pass. Grain dye edges outside the wavelength grid (100 / 900 nm on 400-700) had left one dye
    at 1 everywhere: achromatic grain, with no word."""
    from isettorch.data.natural import grain_dyes

    for cfg, message in (({"components": {"grain": {"enabled": 1}}}, "'components.grain.enabled': expected true or "
                                                                    "false, got 1"),
                         ({"components": {"palette": {"dye": {"probability": False}}}},
                          "'components.palette.dye.probability': expected a probability in [0, 1], got False"),
                         ({"components": {"palette": {"materials": [2.0, 8.0]}}},
                          "'components.palette.materials': expected a range [lo, hi] of two integers")):
        with pytest.raises(ValueError, match="^config: " + re.escape(message)):
            natural_config(cfg)
    assert natural_config({"mean_radiance_scale": 1, "components": {"dead_leaves": {"exponent": 3}}})
    wl = torch.arange(400.0, 701.0, 10.0)
    dyes = grain_dyes(natural_config({}), wl)
    assert torch.allclose(dyes.sum(0), torch.ones_like(wl)) and bool((dyes.amax(1) > 0.9).all())  # three bands
    with pytest.raises(ValueError, match=r"^config: 'components.grain.dye_edges_nm': expected both edges inside the "
                                         r"wavelength grid \(400-700 nm\)"):
        grain_dyes(natural_config({"components": {"grain": {"dye_edges_nm": [100.0, 900.0]}}}), wl)
