"""Camera configs mean what they say: every key is used, booleans are booleans, numbers are finite numbers, and
values that no camera has are errors naming the key (DESIGN.md, principle 5), at build time."""

import copy
import math

import pytest
import torch

from isettorch.camera import Camera, load_yaml
from isettorch.scene import uniform
from isettorch.sensor import Sensor
from isettorch.sensor.filters import filter_set

BASE = {"optics": {"type": "diffraction_limited", "f_number": 4.0, "focal_length_m": 0.004},
        "sensor": {"rows": 16, "cols": 16, "pixel_size_m": 2.8e-6, "cfa": "RGGB", "exposure_s": 0.01,
                   "adc_bits": 10, "conversion_gain_v_per_e": 1e-4, "voltage_swing_v": 1.0},
        "camera": {"noise": False}, "isp": {"demosaic": "bilinear"}}


def _cfg(**sections):
    """BASE with ``section={key: value}`` set (``None`` as a value removes the key)."""
    cfg = copy.deepcopy(BASE)
    for section, keys in sections.items():
        for k, v in keys.items():
            if v is None:
                cfg[section].pop(k, None)
            else:
                cfg[section][k] = v
    return cfg


def _scene(size=48, pitch=2.8e-6, focal=0.004):
    # two scene samples per pixel (no interpolation warning) over 24 pixels: a bright uniform field
    return uniform("D65", size=size, mean_luminance_cd_m2=100.0,
                   hfov_deg=math.degrees(2 * math.atan(size / 2 * pitch / 2 / focal)))


# --- 1: the full well is the saturation that auto-exposure and the white level use -------------------------------
FULL_WELL = {"adc_bits": 12, "full_well_e": 5000.0}


def test_full_well_below_the_swing_sets_the_white_level():
    cfg = _cfg(sensor=dict(FULL_WELL, exposure_s=10.0))  # far past saturation
    cam = Camera.from_config(cfg)
    s = cfg["sensor"]
    lsb_v = s["voltage_swing_v"] / 2 ** s["adc_bits"]
    white = round(s["full_well_e"] * s["conversion_gain_v_per_e"] / lsb_v)  # 5000 e- = 0.5 V = 2048 DN
    assert white == 2048
    out = cam(_scene(), return_intermediates=True)
    assert float(out.raw.data.max()) == white  # the raw clips at the full well ...
    assert out.raw.white_level == white and cam.sensor.white_level_dn == white  # ... and says so (not 4095)
    assert cam.sensor.saturation_v() == pytest.approx(s["full_well_e"] * s["conversion_gain_v_per_e"])
    assert float(out.isp.input.max()) == pytest.approx(1.0)  # the ISP normalises by it: saturated = 1
    # a black level adds to it; an analog gain of 2 doubles the volts: the ADC's top code comes first
    assert Sensor(**dict(s, black_level_dn=64)).white_level_dn == white + 64
    assert Sensor(**dict(s, analog_gain=2.0)).white_level_dn == 2 ** s["adc_bits"] - 1
    # electrons: the full well, not swing / conversion gain (10000 e-)
    assert Sensor(**dict(s, output_units="electrons")).white_level() == s["full_well_e"]


@pytest.mark.parametrize("gain", [1.0, 1.5])
def test_auto_exposure_aims_below_the_full_well(gain):
    cfg = _cfg(sensor=dict(FULL_WELL, auto_exposure="luminance", exposure_s=None, analog_gain=gain))
    cam = Camera.from_config(cfg)
    out = cam(_scene(), return_intermediates=True)
    s = cfg["sensor"]
    white = min(2 ** s["adc_bits"] - 1, round(s["full_well_e"] * s["conversion_gain_v_per_e"] * gain
                                              * 2 ** s["adc_bits"] / s["voltage_swing_v"]))
    assert out.raw.white_level == white
    # ISETCam aeLuminance: the brightest pixel at 0.95 of the saturation, here the full well's, not 0.95 x 4095
    assert float(out.raw.noise_free.max()) == pytest.approx(0.95 * white, rel=1e-5)
    assert float(out.raw.data.max()) < white


def test_per_call_gain_gives_per_item_white_levels():
    s = Sensor(rows=4, cols=4, cfa="mono", adc_bits=12, full_well_e=5000.0)
    raw = s.capture(torch.full((2, 1, 4, 4), 1e9), exposure_s=1.0, analog_gain=torch.tensor([1.0, 4.0]),
                    noise=False)
    assert raw.white_level.tolist() == [2048.0, 4095.0]
    assert raw.normalized().amax((1, 2, 3)).tolist() == [1.0, 1.0]


# --- 2, 8, 10: booleans are booleans, numbers are finite numbers ---------------------------------------------------
@pytest.mark.parametrize("section,key,value", [
    ("sensor", "cds", "no"), ("sensor", "cds", "false"), ("sensor", "learnable_filters", "no"),
    ("sensor", "cds", 0), ("optics", "learn_f_number", "no"),
])
def test_boolean_keys_take_only_yaml_booleans(section, key, value):
    with pytest.raises(TypeError, match=rf"config: {section}\.{key} must be true or false .*got "):
        Camera.from_config(_cfg(**{section: {key: value}}))


def test_boolean_keys_of_pixel_optics():
    cfg = _cfg(sensor={"pixel_optics": {"method": "centred", "diffraction": "false"}})
    with pytest.raises(TypeError, match=r"sensor\.pixel_optics\.diffraction must be true or false.*'false'"):
        Camera.from_config(cfg)
    Camera.from_config(_cfg(sensor={"pixel_optics": {"method": "centred", "diffraction": False}}))  # a real bool


@pytest.mark.parametrize("key,value,error,match", [
    ("fill_factor", "0.9", TypeError, r"sensor\.fill_factor must be a number .*got str \('0\.9'\)"),
    ("fill_factor", [0.5], TypeError, r"sensor\.fill_factor must be a number .*got list"),
    ("seed", "abc", TypeError, r"sensor\.seed must be an integer, got str"),
    ("seed", 1.5, TypeError, r"sensor\.seed must be an integer, got float \(1\.5\)"),
    ("analog_offset_v", float("nan"), ValueError, r"sensor\.analog_offset_v must be a finite number, got nan"),
    ("analog_offset_v", "0.1", TypeError, r"sensor\.analog_offset_v must be a number"),
    ("pixel_size_m", True, TypeError, r"sensor\.pixel_size_m must be a number .*got bool"),
    ("adc_bits", True, TypeError, r"sensor\.adc_bits must be an integer or null, got bool"),
    ("full_well_e", "1000", TypeError, r"sensor\.full_well_e must be a number"),
])
def test_numeric_sensor_keys_are_real_numbers(key, value, error, match):
    with pytest.raises(error, match=match):
        Camera.from_config(_cfg(sensor={key: value}))


def test_numeric_sensor_arguments_reject_bools_and_strings():
    # the constructor too (Python callers): True is no pixel size, a string no percentile
    with pytest.raises(ValueError, match="pixel_size_m: expected a positive number, got True"):
        Sensor(pixel_size_m=True)
    with pytest.raises(ValueError, match="adc_bits: expected None .* got True"):
        Sensor(adc_bits=True)
    with pytest.raises(ValueError, match=r"fill_factor: expected a number in \(0, 1\], got '0.9'"):
        Sensor(fill_factor="0.9")
    with pytest.raises(ValueError, match=r"ae_percentile: expected a percentile in \(0, 100\], got '99'"):
        Sensor(auto_exposure="percentile", ae_percentile="99")
    with pytest.raises(ValueError, match="seed: expected an integer, got 1.5"):
        Sensor(seed=1.5)


@pytest.mark.parametrize("optics,error,match", [
    ({"pad_mode": float("nan")}, ValueError, r"pad_mode: expected .* a finite non-negative number .*got nan"),
    ({"pad_mode": -1}, ValueError, r"pad_mode: expected .* a finite non-negative number .*got -1"),
    ({"max_margin_factor": float("nan")}, ValueError, r"optics\.max_margin_factor must be a finite number"),
    ({"max_margin_factor": -1}, ValueError, r"max_margin_factor: expected a positive finite number .*got -1"),
    ({"learn_f_number": "no"}, TypeError, r"optics\.learn_f_number must be true or false"),
    # 6: no lens in air is faster than f/0.5, none transmits more than it receives
    ({"f_number": 0.4}, ValueError, r"f_number: expected a finite scalar or \[B\] tensor >= 0\.5 .*got 0\.4"),
    ({"transmittance": [0.9, 1.5, 0.9], "transmittance_wavelengths_nm": [400, 550, 700]}, ValueError,
     r"transmittance: expected values in \[0, 1\] .*got a maximum of 1\.5"),
])
def test_optics_values_checked_when_built(optics, error, match):
    with pytest.raises(error, match=match):
        Camera.from_config(_cfg(optics=optics))


def test_fastest_lens_and_full_transmittance_are_accepted():
    cam = Camera.from_config(_cfg(optics={"f_number": 0.5, "transmittance": 1.0}))
    assert float(cam.optics.f_number) == 0.5 and float(cam.optics.transmittance) == 1.0


def test_auto_exposure_target_checked_when_built():
    # at build, as ae_target (it was reported at the first render as 'target:')
    with pytest.raises(ValueError, match=r"ae_target: expected a fraction .* in \(0, 1\], got 2\.0"):
        Camera.from_config(_cfg(sensor={"exposure_s": None, "auto_exposure": "mean", "ae_target": 2.0}))
    with pytest.raises(TypeError, match=r"sensor\.ae_percentile must be a number .*got str \('99'\)"):
        Camera.from_config(_cfg(sensor={"exposure_s": None, "auto_exposure": "percentile", "ae_percentile": "99"}))


# --- 3: a named filter set is used as named ---------------------------------------------------------------------
@pytest.mark.parametrize("cfa,filters,letter", [
    ("YCMY", "nikon_5100", "C"), ("YCMY", "isetcam_rgb", "C"), ("YCMY", "clear", "C"),
    ("YCMY", "sigma_sdmerill", "C"), ("RGBW", "nikon_5100", "W"), ("RGBW", "isetcam_rgb", "W"),
    ("MONO", "isetcam_rgb", "W"),
])
def test_named_filter_set_must_have_every_cfa_letter(cfa, filters, letter):
    with pytest.raises(ValueError, match=rf"filters: the set '{filters}' has no filter for CFA channel '{letter}'"):
        Camera.from_config(_cfg(sensor={"cfa": cfa, "filters": filters}))


def test_without_filters_each_letter_takes_the_library_default():
    w = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    sensor = Sensor(cfa="YCMY")
    cmy = sensor.spectral_qe(w)
    _, ref, letters = filter_set("isetcam_cmy", w, dtype=torch.float64)
    torch.testing.assert_close(cmy, ref[[letters.index(c) for c in sensor.cfa.channel_names]].to(cmy.dtype))
    sensor = Sensor(cfa="RGBW")
    assert sensor.cfa.channel_names == ["R", "G", "B", "W"]
    rgbw = sensor.spectral_qe(w)
    torch.testing.assert_close(rgbw[3], torch.ones_like(rgbw[3]))  # W: clear
    _, rgb, _ = filter_set("isetcam_rgb", w, dtype=torch.float64)
    torch.testing.assert_close(rgbw[:3], rgb.to(rgbw.dtype))


# --- 4: keys nothing would use are errors -------------------------------------------------------------------------
@pytest.mark.parametrize("sections,error,match", [
    ({"sensor": {"ae_target": 0.5}}, ValueError, r"ae_target: 0\.5 tunes auto-exposure, but auto_exposure is None"),
    ({"sensor": {"exposure_s": None, "auto_exposure": "luminance", "ae_percentile": 90}}, ValueError,
     r"ae_percentile: only auto_exposure='percentile' uses it, got auto_exposure='luminance'"),
    ({"sensor": {"adc_bits": None, "black_level_dn": 10.0}}, ValueError,
     r"black_level_dn: 10\.0 DN needs an ADC, but adc_bits is None"),
    ({"isp": {"illuminant_correction": "gray_world", "gains": [1.0, 2.0, 1.0]}}, ValueError,
     r"gains: only illuminant correction 'manual' uses gains; method 'gray_world'"),
    ({"isp": {"scaling": "max", "scaling_percentile": 50}}, ValueError,
     r"scaling_percentile: only scaling 'percentile' uses it, got scaling 'max'"),
    ({"isp": {"sensor_conversion": {"method": "mcc_optimized", "matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}}},
     ValueError, r"isp\.sensor_conversion\.matrix is not used with method 'mcc_optimized'"),
    ({"isp": {"sensor_conversion": {"matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}}},  # the default method fits
     ValueError, r"isp\.sensor_conversion\.matrix is not used with method 'mcc_optimized'"),
    ({"isp": {"sensor_conversion": {"method": "matrix", "matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                                    "illuminant": "A"}}}, ValueError,
     r"isp\.sensor_conversion\.illuminant is not used with method 'matrix'"),
    ({"isp": {"sensor_conversion": {"method": "matrix", "matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
                                    "surfaces": "rawtoaces190"}}}, ValueError,
     r"isp\.sensor_conversion\.surfaces is not used with method 'matrix'"),
])
def test_keys_that_would_be_ignored_are_errors(sections, error, match):
    with pytest.raises(error, match=match):
        Camera.from_config(_cfg(**sections))


def test_the_same_keys_where_they_are_used_load():
    Camera.from_config(_cfg(sensor={"exposure_s": None, "auto_exposure": "percentile", "ae_percentile": 98.0,
                                    "ae_target": 0.8}))
    Camera.from_config(_cfg(sensor={"exposure_s": None, "auto_exposure": "luminance", "ae_target": 0.5}))
    Camera.from_config(_cfg(sensor={"black_level_dn": 64}))
    Camera.from_config(_cfg(isp={"illuminant_correction": "manual", "gains": [1.0, 2.0, 1.0]}))
    Camera.from_config(_cfg(isp={"scaling": "percentile", "scaling_percentile": 50}))
    cam = Camera.from_config(_cfg(isp={"sensor_conversion": {"method": "matrix", "learnable": True,
                                                             "matrix": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}}))
    assert cam.isp.sensor_to_xyz.matrix.requires_grad


def test_a_learnable_fitted_matrix_is_a_parameter_when_the_camera_is_built():
    """With learnable filters, the colour fit waits for the training graph, and a learnable fitted matrix existed
    only after the first render: an optimiser built from the camera's parameters before it never trained the matrix.
    It is the first fit's values, made at build; the first render keeps it, and one step moves it."""
    cam = Camera.from_config(_cfg(sensor={"learnable_filters": True},
                                  isp={"sensor_conversion": {"method": "mcc_optimized", "learnable": True}}))
    params = dict(cam.named_parameters())
    assert "isp.sensor_to_xyz.matrix" in params
    matrix = params["isp.sensor_to_xyz.matrix"]
    start = matrix.detach().clone()
    opt = torch.optim.SGD(cam.parameters(), lr=1e-2)
    from isettorch.scene import macbeth

    cam(macbeth(patch_size=8), generator=torch.Generator().manual_seed(0)).square().mean().backward()
    assert cam.isp.sensor_to_xyz.matrix is matrix and matrix.grad is not None
    opt.step()
    assert not torch.equal(matrix.detach(), start)


# --- 5: NaN, non-positive gains and singular matrices -----------------------------------------------------------
NAN = float("nan")


@pytest.mark.parametrize("isp,match", [
    ({"illuminant_correction": "manual", "gains": [1.0, NAN, 1.0]}, r"gains: expected finite values"),
    ({"illuminant_correction": "manual", "gains": [1.0, -1.0, 1.0]}, r"gains: expected positive per-channel gains"),
    ({"illuminant_correction": "manual", "gains": [1.0, 0.0, 1.0]}, r"gains: expected positive per-channel gains"),
    ({"display": [[NAN, 0, 0], [0, 1, 0], [0, 0, 1]]}, r"display: expected finite values"),
    ({"display": [[0, 0, 0], [0, 0, 0], [0, 0, 0]]}, r"display: the RGB -> XYZ matrix is singular"),
    ({"display": [[0.4, 0.4, 0.2], [0.2, 0.2, 0.6], [0.1, 0.1, 0.9]]}, r"display: the RGB -> XYZ matrix is singular"),
    ({"sensor_conversion": {"method": "matrix", "matrix": [[NAN, 0, 0], [0, 1, 0], [0, 0, 1]]}},
     r"matrix: expected finite values"),
    # (named the stages' arguments, method / border / space, not the config's keys; a bad fallback was accepted and,
    # with an RGBW sensor, refused at the first render)
    ({"demosaic": "bilinar"}, r"^config: isp.demosaic: expected one of"),
    ({"demosaic_border": "mirror"}, r"^config: isp.demosaic_border: expected 'method' or 'reflect'"),
    ({"demosaic_fallback": "foo"}, r"^config: isp.demosaic_fallback: expected a method for index-map CFAs"),
    ({"correction_space": "rgb"}, r"^config: isp.correction_space: expected 'xyz' or 'sensor', got 'rgb'"),
])
def test_invalid_isp_values_are_errors(isp, match):
    with pytest.raises(ValueError, match=match):
        Camera.from_config(_cfg(isp=isp))


def test_illuminant_names_are_checked_when_built():
    with pytest.raises(ValueError, match=r"illuminant: 'D66' is not a valid illuminant name; expected one of "
                                         r"\['D65'.*'D<cct>' \(CIE daylight at a CCT of 4000-25000 K"):
        Camera.from_config(_cfg(isp={"sensor_conversion": {"illuminant": "D66"}}))
    with pytest.raises(ValueError, match=r"correction_white: 'D66' is not a valid illuminant name"):
        Camera.from_config(_cfg(isp={"correction_white": "D66"}))
    Camera.from_config(_cfg(isp={"sensor_conversion": {"illuminant": "D5000"}}))  # a valid D<cct>


# --- 8, 12: pixel optics geometry -----------------------------------------------------------------------------
@pytest.mark.parametrize("pixel_optics,match", [
    ({"method": "centred", "pixel_size_m": 10e-6},
     r"pixel_optics\.pixel_size_m: 1e-05 m differs from the sensor's pixel_size_m 2\.8e-06 m"),
    ({"method": "centred", "microlens_f_number": 2.5, "microlens_diameter_m": 1e-6},
     r"microlens_f_number, microlens_diameter_m: give one of them"),
    ({"method": "centred", "samples": [0, 0]}, r"samples: expected two positive integers .*got \[0, 0\]"),
    ({"method": "centred", "wavelength_nm": "500"}, r"wavelength_nm: expected a positive number, got '500'"),
])
def test_contradictory_or_invalid_pixel_optics(pixel_optics, match):
    with pytest.raises(ValueError, match=match):
        Camera.from_config(_cfg(sensor={"pixel_optics": pixel_optics}))


def test_pixel_optics_with_the_sensor_pitch_loads():
    cam = Camera.from_config(_cfg(sensor={"pixel_optics": {"method": "centred", "pixel_size_m": 2.8e-6,
                                                           "microlens_diameter_m": 2.8e-6}}))
    assert cam.sensor.pixel_optics.pixel["pixel_size_m"] == 2.8e-6


# --- 9: YAML 1.2 floats ------------------------------------------------------------------------------------------
def test_yaml_scientific_notation_is_a_number(tmp_path):
    assert load_yaml("a: 1e-2\nb: 1.0e4\nc: -1E+3\nd: .5e3\ne: 2.8e-6\nf: '1e-2'\ng: 12\nh: 1.0.1") == {
        "a": 0.01, "b": 10000.0, "c": -1000.0, "d": 500.0, "e": 2.8e-6, "f": "1e-2", "g": 12, "h": "1.0.1"}
    path = tmp_path / "cam.yaml"
    path.write_text("optics: {f_number: 4.0, focal_length_m: 4.0e-3}\n"
                    "sensor: {rows: 16, cols: 16, exposure_s: 1e-2, full_well_e: 1.0e4, adc_bits: 10}\n")
    cam = Camera.from_config(path)
    assert cam.sensor.exposure_s == 0.01 and cam.sensor.noise_terms.full_well_e == 10000.0
    sensor = Sensor.from_config(path)  # the sensor's own loader reads it the same way
    assert sensor.exposure_s == 0.01 and sensor.noise_terms.full_well_e == 10000.0
    path.write_text("sensor: {rows: 16, cols: 16, cds: 'no'}\n")
    with pytest.raises(TypeError, match=r"sensor\.cds must be true or false"):
        Sensor.from_config(path)


def test_a_section_given_twice_or_as_a_list_is_refused(tmp_path):
    from isettorch.camera import Camera

    dup = tmp_path / "dup.yaml"  # (PyYAML kept the second sensor: imx363, without a word)
    dup.write_text("optics: {type: diffraction_limited}\nsensor: {preset: isetcam_default}\nsensor: {preset: imx363}\n")
    with pytest.raises(Exception, match="found the key 'sensor' twice"):
        Camera.from_config(str(dup))
    # YAML merge keys are not duplicates: an anchored mapping overriding a key it merged, merged again
    merged = "defaults: &d {gain: 1}\npresets:\n  p1: &p1\n    <<: *d\n    gain: 2\np2:\n  <<: *p1\n"
    assert load_yaml(merged) == {"defaults": {"gain": 1}, "presets": {"p1": {"gain": 2}}, "p2": {"gain": 2}}
    with pytest.raises(ValueError, match="sensor: expected a mapping"):  # (a bare Sensor(), silently)
        Camera.from_config({"optics": {"type": "diffraction_limited"}, "sensor": []})
    with pytest.raises(ValueError, match="isp: expected a mapping"):
        Camera.from_config({"optics": {"type": "diffraction_limited"}, "sensor": {}, "isp": "malvar"})


def test_sensor_values_of_the_wrong_type_are_named():
    base = {"optics": {"type": "diffraction_limited"}}
    with pytest.raises(ValueError, match="sensor.exposure_s: expected a number or a list of numbers"):
        Camera.from_config({**base, "sensor": {"exposure_s": [0.01, "a"]}})
    with pytest.raises(ValueError, match="sensor.preset: expected a preset name"):
        Camera.from_config({**base, "sensor": {"preset": 5}})


def test_camera_call_arguments_name_themselves():
    """A tensor or None given as the scene raised an AttributeError about 'height'; return_intermediates='no' read
    as true; isp='x' was accepted and failed at the first call."""
    from isettorch.optics import DiffractionLimitedOptics

    cam = Camera(DiffractionLimitedOptics(), Sensor(rows=8, cols=8, exposure_s=1e-3), noise=False)
    for bad in (torch.ones(1, 31, 8, 8), None):
        with pytest.raises(TypeError, match="scene: expected an isettorch Scene"):
            cam(bad)
    with pytest.raises(TypeError, match="return_intermediates"):
        cam(uniform("D65", 8), "no")
    with pytest.raises(TypeError, match="isp: expected None or an nn.Module"):
        Camera(DiffractionLimitedOptics(), Sensor(rows=8, cols=8), isp="x")


@pytest.mark.parametrize("sections, match", [
    ({"sensor": {"auto_exposure": "mean"}},  # (BASE has exposure_s 0.01: accepted, every capture auto-exposed)
     r"config: sensor\.exposure_s 0\.01 is not used with sensor\.auto_exposure 'mean'"),
    ({"sensor": {"exposure_s": []}}, r"exposure_s: expected a number or one per batch item, got an empty list"),
    ({"isp": {"sensor_conversion": {"method": "mcc_optimized", "surfaces": "macbth"}}},
     r"config: isp\.sensor_conversion\.surfaces: unknown reflectance set 'macbth'"),
    ({"isp": {"sensor_conversion": {"method": "mcc_optimized", "observer": "1931x"}}},
     r"config: isp\.sensor_conversion: observer"),
    ({"sensor": {"cfa": "QUAD_BAYER"}, "isp": {"demosaic_border": "reflect"}},
     r"config: isp\.demosaic_border 'reflect' needs a CFA cell of at most 2x2, and sensor\.cfa has a 4x4 cell"),
    ({"isp": {"illuminant_correction": "manual", "gains": [1.0, 1.0]}},
     r"config: isp\.gains has 2 values, and the correction in xyz space"),
    ({"isp": {"sensor_conversion": {"method": "matrix", "matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]}}},
     r"config: isp\.sensor_conversion\.matrix has 4 columns, and sensor\.cfa has 3 channels"),
])
def test_what_a_render_would_refuse_is_refused_at_build_naming_the_key(sections, match):
    """These passed from_config and failed in the first render, naming an internal argument (border, gains, name,
    min() of an empty sequence) or nothing of the config (2026-12-02 CLI audit)."""
    with pytest.raises(ValueError, match=match):
        Camera.from_config(_cfg(**sections))


def test_a_configs_files_are_relative_to_its_folder(tmp_path, monkeypatch):
    """A psf_file's path in a camera YAML (or a synth config's camera.optics) is relative to the YAML's folder: it
    was relative to the current folder, so the config failed from elsewhere, or read another file of that name."""
    import numpy as np
    import yaml

    from isettorch.data.config import load_config as load_synth_config
    from isettorch.optics.factory import resolve_config_paths

    folder = tmp_path / "cams"
    folder.mkdir()
    psf = np.zeros((5, 5))
    psf[2, 2] = 1.0
    np.savez(folder / "psf.npz", psf=psf, psf_spacing_m=1e-6)
    cfg = _cfg(optics={"type": "psf_file", "path": "psf.npz", "f_number": None, "focal_length_m": None})
    (folder / "cam.yaml").write_text(yaml.safe_dump(cfg))
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    cam = Camera.from_config(str(folder / "cam.yaml"))
    assert type(cam.optics).__name__ == "ShiftInvariantOptics"
    (folder / "synth.yaml").write_text(yaml.safe_dump({"camera": {"optics": {"type": "psf_file", "path": "psf.npz"}}}))
    assert load_synth_config(folder / "synth.yaml")["camera"]["optics"]["path"] == str(folder / "psf.npz")
    # a bundled lens's name stays a name, a lens file is a path; absolute paths and other types are left alone
    assert resolve_config_paths({"type": "lens", "lens": "cooke_triplet"}, folder)["lens"] == "cooke_triplet"
    assert resolve_config_paths({"type": "lens", "lens": "my.zmx"}, folder)["lens"] == str(folder / "my.zmx")
    assert resolve_config_paths({"type": "psf_file", "path": "/abs/p.npz"}, folder)["path"] == "/abs/p.npz"
    assert resolve_config_paths({"type": "diffraction_limited", "path": "x"}, folder) == {
        "type": "diffraction_limited", "path": "x"}


def test_synth_refuses_an_f_number_beside_configured_optics():
    """camera.f_number / focal_length_m were ignored when camera.optics was set (the optics' own were used) though
    the manifest recorded them."""
    from isettorch.data.config import merge_config

    optics = {"type": "diffraction_limited", "f_number": 8.0}
    with pytest.raises(ValueError, match=r"camera\.f_number: camera\.optics is set"):
        merge_config({"camera": {"optics": optics, "f_number": [1.4]}})
    with pytest.raises(ValueError, match=r"camera\.focal_length_m: camera\.optics is set"):
        merge_config({"camera": {"optics": optics, "focal_length_m": 0.05}})
    assert merge_config({"camera": {"optics": optics}})["camera"]["optics"] == optics


def test_a_config_that_is_not_utf8_is_named(tmp_path):
    """The codec's own message named no file ("'utf-8' codec can't decode byte 0xff ...")."""
    bad = tmp_path / "bad.yaml"
    bad.write_bytes(b"\xff\xfe sensor: 1")
    with pytest.raises(ValueError, match=r"path: '.*bad\.yaml': not UTF-8 text"):
        Camera.from_config(str(bad))


def test_a_per_item_exposure_list_keeps_its_values():
    """exposure_s: [0.01, 0.01] was made a float32 tensor (0.009999999776), so a float64 render differed from the
    scalar 0.01's by 2e-8 relative; the list is float64 now, the value given."""
    cam = Camera.from_config(_cfg(sensor={"exposure_s": [0.01, 0.02]}))
    assert cam.sensor.exposure_s.dtype == torch.float64 and cam.sensor.exposure_s.tolist() == [0.01, 0.02]
