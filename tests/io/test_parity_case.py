"""Reading and writing ISETCam parity cases (isetcam-parity/FORMAT.md) and the objects a case describes."""

from pathlib import Path

import numpy as np
import pytest
import torch

from isettorch.io import isetcam as io

CASE = Path("/work/shared/isetcam-parity/macbeth_d65_default.npz")


def test_write_read_round_trip_without_pickle(tmp_path):
    case = {"sensor_cfa": np.str_("GBRG"), "sensor_rows": np.int64(4), "wavelengths_nm": torch.tensor([400.0, 410.0]),
            "sensor_filter_names": np.array(["rDefault", "gDefault", "bDefault"])}
    io.write_parity_case(tmp_path / "c.npz", case)
    back = io.read_parity_case(tmp_path / "c.npz")
    assert str(back["sensor_cfa"]) == "GBRG" and int(back["sensor_rows"]) == 4
    np.testing.assert_array_equal(back["wavelengths_nm"], [400.0, 410.0])
    with pytest.raises(ValueError, match=r"case\['bad'\]"):
        io.write_parity_case(tmp_path / "d.npz", {"bad": np.array([{}, 1], dtype=object)})
    with pytest.raises(ValueError, match="no such parity case"):
        io.read_parity_case(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_text("not a zip")
    with pytest.raises(ValueError, match="not a readable parity case"):
        io.read_parity_case(tmp_path / "junk.npz")


@pytest.mark.parametrize("text,bits", [("analog", None), ("10", 10), ("8 bit", 8), ("", None)])
def test_adc_bits(text, bits):
    assert io.case_adc_bits({"sensor_quantization": np.str_(text)}) == bits


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
    with pytest.raises(KeyError, match="scene_photons"):
        io.case_scene_oi({k: v for k, v in case.items() if k != "scene_photons"})
