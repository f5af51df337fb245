"""Reading and writing ISETCam parity cases (isetcam-parity/FORMAT.md) and the objects a case describes."""

import re

import numpy as np
import pytest
import torch
from shared_paths import PARITY_CASE

from isettorch.io import isetcam as io

CASE = PARITY_CASE


def test_write_read_round_trip_without_pickle(tmp_path):
    case = {"sensor_cfa": np.str_("GBRG"), "sensor_rows": np.int64(4), "wavelengths_nm": torch.tensor([400.0, 410.0]),
            "sensor_filter_names": np.array(["rDefault", "gDefault", "bDefault"])}
    io.write_parity_case(tmp_path / "c.npz", case)
    back = io.read_parity_case(tmp_path / "c.npz", check=False)  # a partial case: FORMAT.md's keys not checked
    assert str(back["sensor_cfa"]) == "GBRG" and int(back["sensor_rows"]) == 4
    np.testing.assert_array_equal(back["wavelengths_nm"], [400.0, 410.0])
    with pytest.raises(ValueError, match=r"case\['bad'\]"):
        io.write_parity_case(tmp_path / "d.npz", {"bad": np.array([{}, 1], dtype=object)})
    with pytest.raises(ValueError, match="no such parity case"):
        io.read_parity_case(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_text("not a zip")
    with pytest.raises(ValueError, match="not an .npz"):
        io.read_parity_case(tmp_path / "junk.npz")


@pytest.mark.parametrize("text,bits", [("analog", None), ("10", 10), ("8 bit", 8), (" 12-bit ", 12)])
def test_adc_bits(text, bits):
    assert io.case_adc_bits({"sensor_quantization": np.str_(text)}) == bits


@pytest.mark.parametrize("text", ["", "0", "linear", "10.5", "64"])
def test_adc_bits_refuses_other_text(text):
    with pytest.raises(ValueError, match="sensor_quantization: expected 'analog' or a bit count"):
        io.case_adc_bits({"sensor_quantization": np.str_(text)})


def test_cfa_from_pattern_and_names():
    """FORMAT.md 2: the CMY sensor 'YCMY' = [[2, 1], [3, 2]] over (cDefault, yDefault, mDefault)."""
    cfa = io.case_cfa({"sensor_filter_names": np.array(["cDefault", "yDefault", "mDefault"]),
                       "sensor_cfa_pattern": np.array([[2, 1], [3, 2]]), "sensor_cfa": np.str_("YCMY")})
    assert cfa.pattern == "YCMY" and list(cfa.channel_names) == ["C", "Y", "M"]
    with pytest.raises(ValueError, match="sensor_cfa_pattern"):
        io.case_cfa({"sensor_filter_names": np.array(["w"]), "sensor_cfa_pattern": np.array([[1, 2]])})


@pytest.mark.skipif(not CASE.exists(), reason="ISETCam parity case not available")
def test_public_case_objects():
    case = io.read_parity_case(CASE)
    s = io.case_sensor(case)
    assert (s.rows, s.cols) == (int(case["sensor_rows"]), int(case["sensor_cols"]))
    assert s.cfa.pattern == "GBRG" and s.sampling == "isetcam" and s.gain_convention == "isetcam"
    oi = io.case_optical_image(case)
    assert oi.photons.shape[1:] == case["oi_photons"].shape and oi.pad_rows == int(case["oi_pad_rows"])
    ours = io.case_scene_oi(case)
    ref = case["oi_photons"].astype(np.float64)
    m = ref > 0.01 * ref.max()
    assert (np.abs(ours.photons[0].numpy() - ref)[m] / ref[m]).max() < 1e-4  # measured 3.2e-6
    with pytest.raises(ValueError, match=r"^missing required key 'scene_photons' \(FORMAT.md section 3\)$"):
        io.case_scene_oi({k: v for k, v in case.items() if k != "scene_photons"})


# --- variants of the shipped case: how MATLAB / other exporters write the same values (the audit's defects 1-9) ---

needs_case = pytest.mark.skipif(not CASE.exists(), reason="ISETCam parity case not available")
FORMAT_MD = CASE.parent / "FORMAT.md"


@pytest.fixture(scope="module")
def base():
    return io.read_parity_case(CASE)


def variant(base, **changes):
    """The shipped case with keys replaced (a value None drops the key)."""
    out = dict(base)
    for k, v in changes.items():
        if v is None:
            out.pop(k, None)
        else:
            out[k] = v
    return out


def raises(case, message):
    """check_parity_case fails with exactly ``message``."""
    with pytest.raises(ValueError) as err:
        io.check_parity_case(case)
    assert str(err.value) == message


@pytest.mark.skipif(not FORMAT_MD.exists(), reason="FORMAT.md not available")
def test_required_is_format_sections_3_table():
    """REQUIRED is FORMAT.md section 3's "Required keys (present in every case)" table, in order, except sensor_dv
    ("Only in quantized cases", required by check_parity_case when the sensor is quantized)."""
    import re

    text = FORMAT_MD.read_text()
    table = text.split("Required keys (present in every case):")[1].split("Noise keys:")[0]
    keys = [k for line in table.splitlines() if line.startswith("| `")
            for k in re.findall(r"`([a-z0-9_]+)`", line.split("|")[1])]
    assert "sensor_dv" in keys
    assert tuple(k for k in keys if k != "sensor_dv") == io.REQUIRED


@needs_case
@pytest.mark.parametrize("key", io.REQUIRED)
def test_missing_required_key(base, key):
    """Defect 6: a missing required key is an error naming it (was: skipped or defaulted)."""
    raises(variant(base, **{key: None}), f"missing required key {key!r} (FORMAT.md section 3)")


@needs_case
def test_optional_keys_stay_optional(base):
    io.check_parity_case({k: base[k] for k in io.REQUIRED})  # FORMAT.md 3: everything else is optional


@needs_case
def test_reference_images_must_be_finite(base):
    # a NaN reference scored as a stage FAIL (exit 1) and printed a bare NaN in --json
    volts = base["sensor_volts"].astype(np.float64).copy()
    volts[0, 0] = np.nan
    raises(variant(base, sensor_volts=volts), "sensor_volts: expected finite values, got 1 NaN/Inf")


def test_cli_json_has_no_bare_nan():
    import json

    from isettorch.commands._outputs import strict_json

    text = strict_json({"err": float("nan"), "rows": [1.0, float("inf"), {"x": -float("inf")}]})
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"bare {c}")) == {"err": None,
                                                                                  "rows": [1.0, None, {"x": None}]}


@needs_case
def test_sensor_dv_required_exactly_when_quantized(base):
    dv = np.floor(base["sensor_volts"].astype(np.float64) * 1024 + 0.5).astype(np.float32)
    q10 = dict(sensor_quantization=np.str_("10"), sensor_quantization_bits=np.int64(10))
    io.check_parity_case(variant(base, sensor_dv=dv, **q10))
    raises(variant(base, **q10), "missing required key 'sensor_dv' (FORMAT.md section 3: every quantized case holds "
                                 "it; sensor_quantization is '10')")
    raises(variant(base, sensor_dv=dv), "sensor_dv: the case is analog (sensor_quantization 'analog'), but "
                                        "FORMAT.md section 3 has sensor_dv only in quantized cases")
    # the required sensor_quantization decides; the optional sensor_quantization_bits (0 here) is not read
    io.check_parity_case(variant(base, sensor_dv=dv, sensor_quantization=np.str_("10")))


@needs_case
@pytest.mark.parametrize("shape", [(1,), (1, 1)])
def test_scalars_of_size_one(base, shape):
    """Defect 1: MATLAB exports scalars as 1x1 (or 1-element) arrays; they read as the 0-d values."""
    v = {k: (a.reshape(shape) if a.ndim == 0 and a.dtype.kind in "fi" else a) for k, a in base.items()}
    io.check_parity_case(v)
    a, b = io.case_sensor(v), io.case_sensor(base)
    assert (a.rows, a.cols, a.pixel_size_m, a.fill_factor) == (b.rows, b.cols, b.pixel_size_m, b.fill_factor)
    assert float(a.exposure_s) == float(b.exposure_s) and a.analog_gain == b.analog_gain
    oi = io.case_optical_image(v)
    assert (oi.pad_rows, oi.pad_cols) == (int(base["oi_pad_rows"]), int(base["oi_pad_cols"]))


@needs_case
def test_scalar_and_integer_errors(base):
    raises(variant(base, sensor_exposure_s=np.array([0.05, 0.06])),
           "sensor_exposure_s: expected a scalar (an array of size 1), got shape (2,)")
    raises(variant(base, sensor_rows=np.float64(198.5)), "sensor_rows: expected an integer, got 198.5")
    raises(variant(base, oi_pad_cols=np.array([[12.5]])), "oi_pad_cols: expected an integer, got 12.5")
    raises(variant(base, sensor_fill_factor=np.str_("0.75")),
           "sensor_fill_factor: expected numbers, got a <U4 array of shape ()")
    assert io.case_sensor(variant(base, sensor_rows=np.float64(198.0))).rows == 198  # integral floats are fine


TEN = [np.str_("10"), np.array(["10"]), np.array([["10"]]), np.array(["1", "0"]), np.array([["1", "0"]]),
       np.bytes_(b"10"), np.array([b"1", b"0"]), np.array([b"10"]), np.str_(" 10 ")]


@pytest.mark.parametrize("value", TEN, ids=lambda v: f"{type(v).__name__}{np.shape(v)}")
def test_strings_as_exported(value):
    """Defect 2: 0-d, size-1, cell ([1, 1]) and char-array strings, and bytes, all read as '10' (a char array
    ['1', '0'] was read as "['1' '0']", i.e. 1 bit)."""
    assert io._string(value, "sensor_quantization") == "10"
    assert io.case_adc_bits({"sensor_quantization": value}) == 10


@pytest.mark.parametrize("value,shape", [(np.array(["ab", "cd"]), "(2,)"),
                                         (np.array([["a", "b"], ["c", "d"]]), "(2, 2)"), (np.float64(10.0), "()")])
def test_string_errors_name_the_key(value, shape):
    with pytest.raises(ValueError, match=rf"^optics_offaxis: expected a string .*, got a \S+ array of shape "
                                         rf"{re.escape(shape)}$"):
        io._string(value, "optics_offaxis")


@needs_case
@pytest.mark.parametrize("shape", [(1, 3), (3, 1)])
def test_filter_names_as_2d_cell(base, shape):
    """Defect 3: names exported as a [1, C] or [C, 1] cell array."""
    v = variant(base, sensor_filter_names=base["sensor_filter_names"].reshape(shape))
    io.check_parity_case(v)
    assert io.case_cfa(v).pattern == "GBRG" and io.case_cfa(v).channel_names == io.case_cfa(base).channel_names
    bad = np.array([["rDefault", "gDefault"], ["bDefault", "x"]])
    raises(variant(base, sensor_filter_names=bad),
           "sensor_filter_names: expected a list of strings [C] (or [1, C] / [C, 1]), got shape (2, 2)")


@needs_case
def test_spectral_qe_must_be_c_by_l(base):
    """Defect 4: a transposed [L, C] QE was silently reshaped (scrambled); FORMAT.md fixes [C, L]."""
    raises(variant(base, sensor_spectral_qe=base["sensor_spectral_qe"].T.copy()),
           "sensor_spectral_qe: expected shape (C, L) = (3, 31) (3 filters in sensor_filter_names, 31 wavelengths in "
           "wavelengths_nm), got (31, 3) (an [L, C] array, transposed: FORMAT.md sections 2-3 store row k = filter k)")
    raises(variant(base, sensor_spectral_qe=np.vstack([base["sensor_spectral_qe"]] * 2)[:4]),
           "sensor_spectral_qe: expected shape (C, L) = (3, 31) (3 filters in sensor_filter_names, 31 wavelengths in "
           "wavelengths_nm), got (4, 31)")
    raises(variant(base, sensor_spectral_qe=base["sensor_spectral_qe"][:, :30]),
           "sensor_spectral_qe: expected shape (C, L) = (3, 31) (3 filters in sensor_filter_names, 31 wavelengths in "
           "wavelengths_nm), got (3, 30)")


@needs_case
def test_per_wavelength_lengths(base):
    """Defect 5: a wrong-length [L] key was an einsum traceback; it is an error naming the key at read time."""
    raises(variant(base, vlambda=base["vlambda"][:30]),
           "vlambda: expected 31 values (one per wavelength in wavelengths_nm), got shape (30,)")
    raises(variant(base, optics_transmittance=np.ones(32)),
           "optics_transmittance: expected 31 values (one per wavelength in wavelengths_nm), got shape (32,)")
    raises(variant(base, scene_photons=base["scene_photons"][:30]),
           "scene_photons: expected [L, H, W] with L = 31 (wavelengths_nm), got shape (30, 64, 96)")
    raises(variant(base, oi_photons=base["oi_photons"][:, 1:]),
           "oi_photons: expected shape (31, 80, 120) ([L, H + 2 oi_pad_rows, W + 2 oi_pad_cols], FORMAT.md section 3), "
           "got (31, 79, 120)")
    io.check_parity_case(variant(base, vlambda=base["vlambda"].reshape(1, -1),
                                 optics_transmittance=base["optics_transmittance"].reshape(-1, 1)))
    from isettorch.optics.isetcam import mean_illuminance

    with pytest.raises(ValueError, match="vlambda, photons: expected 31 values"):
        mean_illuminance(torch.ones(1, 31, 2, 2), torch.arange(400.0, 701.0, 10.0), torch.ones(30))


def test_wavelength_weights_rules():
    """Defect 7: ISETCam's rule (FORMAT.md 4.1) is w[1] - w[0] for every band; the library keeps the midpoint rule."""
    from isettorch import spectral

    uniform = torch.arange(400.0, 701.0, 10.0, dtype=torch.float64)
    assert torch.equal(spectral.wavelength_weights(uniform, rule="isetcam"), spectral.wavelength_weights(uniform))
    w = torch.tensor([400.0, 420.0, 450.0, 500.0, 550.0], dtype=torch.float64)
    assert spectral.wavelength_weights(w).tolist() == [20.0, 25.0, 40.0, 50.0, 50.0]  # default unchanged
    assert spectral.wavelength_weights(w, rule="isetcam").tolist() == [20.0] * 5
    assert spectral.wavelength_weights(w[:1], rule="isetcam").tolist() == [1.0]
    with pytest.raises(ValueError, match="rule: expected one of"):
        spectral.wavelength_weights(w, rule="trapezoid")


@needs_case
def test_case_sensor_integrates_with_isetcams_rule_on_a_nonuniform_grid(base):
    """Defect 7: the case's Sensor gives binwidth * sum(QE * photons) with binwidth = w[1] - w[0] for every band."""
    idx = [0, 2, 5, 10, 15, 20, 25, 30]
    v = variant(base, wavelengths_nm=base["wavelengths_nm"][idx], sensor_spectral_qe=base["sensor_spectral_qe"][:, idx],
                scene_photons=base["scene_photons"][idx], oi_photons=base["oi_photons"][idx],
                optics_transmittance=base["optics_transmittance"][idx], vlambda=base["vlambda"][idx])
    oi = io.case_optical_image(v)
    density = io.case_sensor(v).electron_rate_density(oi)[0].numpy()
    expected = 20.0 * np.einsum("lhw,cl->chw", v["oi_photons"].astype(np.float64), v["sensor_spectral_qe"])
    np.testing.assert_allclose(density, expected, rtol=1e-12)


@needs_case
def test_not_an_npz(tmp_path, base):
    """Defect 8: a text file or a .npy named .npz is "not an .npz (zip) archive" (was: pickled data / TypeError)."""
    (tmp_path / "text.npz").write_text("hello")
    np.save(tmp_path / "array.npy", np.arange(3))
    (tmp_path / "array.npy").rename(tmp_path / "array.npz")
    for name in ("text.npz", "array.npz"):
        with pytest.raises(ValueError) as err:
            io.read_parity_case(tmp_path / name)
        assert str(err.value) == f"path: {str(tmp_path / name)!r} is not an .npz (zip) archive"
    import zipfile

    with zipfile.ZipFile(tmp_path / "notes.npz", "w") as z:
        z.writestr("a.txt", "not an array")
    with pytest.raises(ValueError, match="member 'a.txt' is not a .npy array"):
        io.read_parity_case(tmp_path / "notes.npz")
    np.savez(tmp_path / "objects.npz", **variant(base, meta=np.array([{"a": 1}], dtype=object)))
    with pytest.raises(ValueError, match=r"member 'meta' holds an object array \(pickled data\)"):
        io.read_parity_case(tmp_path / "objects.npz")


@needs_case
@pytest.mark.parametrize("value,mode", [("cos4th", "cos4th"), ("COS4TH", "cos4th"), ("skip", "skip"),
                                        ("none", "skip"), (np.array(["skip"]), "skip")])
def test_offaxis_values(base, value, mode):
    assert io.case_offaxis(variant(base, optics_offaxis=np.asarray(value))) == mode


@needs_case
def test_offaxis_unknown_is_an_error(base):
    """Defect 9: an unknown optics_offaxis was treated as cos4th."""
    raises(variant(base, optics_offaxis=np.str_("cos3th")),
           "optics_offaxis: expected one of 'cos4th', 'skip', 'none' (FORMAT.md section 3: 'cos4th' in every case), "
           "got 'cos3th'")


def test_sensor_spectral_rule_is_checked_and_in_isetcams_conventions():
    """The quadrature is a Sensor option (``spectral_rule``) that ISETCAM_CONVENTIONS sets to ISETCam's rule."""
    from isettorch.sensor import ISETCAM_CONVENTIONS, Sensor

    assert ISETCAM_CONVENTIONS["spectral_rule"] == "isetcam"
    assert Sensor(rows=2, cols=2).spectral_rule == "midpoint"
    with pytest.raises(ValueError, match=r"spectral_rule: expected one of \('midpoint', 'isetcam'\), got 'trapezoid'"):
        Sensor(rows=2, cols=2, spectral_rule="trapezoid")


def test_cfa_errors_name_the_case_keys(base):
    """A 3-letter cell without its pattern named the library's 'cell' argument and an 'RG/GB' syntax a case cannot
    hold; filters that disagree with the cell named 'channel_names' (parity audit, 2026-12-01)."""
    from isettorch.io.isetcam import case_cfa

    case = {k: v for k, v in base.items() if k != "sensor_cfa_pattern"}
    with pytest.raises(ValueError, match=r"sensor_cfa: 'RGB' is not a square cell \(3 letters\) and the case has no "
                                         r"sensor_cfa_pattern"):
        case_cfa(dict(case, sensor_cfa=np.str_("RGB")))
    with pytest.raises(ValueError, match=r"^sensor_cfa / sensor_cfa_pattern, sensor_filter_names / "
                                         r"sensor_filter_letters: the cell and the filters disagree"):
        case_cfa(dict(case, sensor_cfa=np.str_("RGGX")))
