"""ISETCam scene .mat import: struct layout (scene.data.photons, scene.spectrum.wave, wAngular, distance)."""

import h5py
import numpy as np
import pytest
import scipy.io
import torch

from isettorch.io import read_isetcam_scene


def _scene_struct(photons, wave, **extra):
    s = {"type": "scene", "name": "unit test", "data": {"photons": photons}, "spectrum": {"wave": wave},
         "wAngular": 12.5, "distance": 2.0}
    s.update(extra)
    return s


def test_reads_isetcam_struct_layout(tmp_path):
    rng = np.random.default_rng(1)
    wave = np.arange(400.0, 701.0, 10.0)
    photons = (rng.random((5, 7, wave.size)) * 1e15).astype(np.float32)  # (rows, cols, wave)
    ill = np.linspace(1e15, 2e15, wave.size)
    scipy.io.savemat(tmp_path / "s.mat", {"scene": _scene_struct(photons, wave,
                                                                  illuminant={"data": {"photons": ill}})})
    s = read_isetcam_scene(tmp_path / "s.mat")
    assert s.photons.shape == (1, 31, 5, 7)
    # ISETCam (row, col, wave) -> isettorch [B, wave, row, col]
    assert float(s.photons[0, 4, 2, 6]) == float(photons[2, 6, 4])
    assert torch.equal(s.photons[0], torch.from_numpy(photons).permute(2, 0, 1))
    assert s.wavelengths_nm.tolist() == wave.tolist()
    assert float(s.hfov_deg[0]) == 12.5 and float(s.distance_m[0]) == 2.0
    assert s.name == "unit test"
    torch.testing.assert_close(s.illuminant_photons[0], torch.tensor(ill, dtype=torch.float32))


def test_compressed_photons_are_decoded(tmp_path):
    wave = np.array([450.0, 550.0, 650.0])
    codes = np.array([[[0, 65535, 32768]]], dtype=np.uint16)  # (1, 1, 3)
    data = {"photons": codes, "dmin": 1e14, "dmax": 3e14, "bitDepth": 16}
    scipy.io.savemat(tmp_path / "c.mat", {"scene": {"data": data, "spectrum": {"wave": wave}, "wAngular": 5.0,
                                                    "distance": 1.2}})
    s = read_isetcam_scene(tmp_path / "c.mat", dtype=torch.float64)
    expected = 1e14 + codes[0, 0].astype(float) * 2e14 / 65535  # ieUncompressData
    np.testing.assert_allclose(s.photons[0, :, 0, 0].numpy(), expected, rtol=1e-12)


def test_a_compressed_illuminant_is_decoded_as_isetcam_does(tmp_path):
    """Old files keep the illuminant as uint32 codes with data.min / data.max (ISETCam illuminantGet 'photons':
    ieUncompressData(photons, min, max, 32)); the codes were read as photons (3.2e9 for 3e15: 1e6x too dim)."""
    wave = np.array([[400.0, 500.0, 600.0]])
    codes = np.array([[[0, 100, 65535]] * 2] * 2, dtype=np.uint16)
    lo, hi = 0.0, 4e15
    ill_codes = np.array([[1073741824, 2147483648, 3221225471]], dtype=np.uint32)
    scene = _scene_struct(codes, wave, data={"photons": codes, "dmin": 1e14, "dmax": 1e16, "bitDepth": 16.0},
                          illuminant={"data": {"photons": ill_codes, "min": lo, "max": hi}, "spectrum": {"wave": wave}})
    scipy.io.savemat(tmp_path / "old.mat", {"scene": scene})
    s = read_isetcam_scene(tmp_path / "old.mat", dtype=torch.float64)
    expected = lo + ill_codes[0].astype(float) * (hi - lo) / (2**32 - 1)  # 1e15, 2e15, 3e15 to 3e-10
    np.testing.assert_allclose(s.illuminant_photons[0].numpy(), expected, rtol=1e-12)
    np.testing.assert_allclose(expected, [1e15, 2e15, 3e15], rtol=1e-9)
    scene["illuminant"]["data"] = {"photons": ill_codes}
    scipy.io.savemat(tmp_path / "bad.mat", {"scene": scene})
    with pytest.raises(ValueError, match=r"scene\.illuminant\.data: uint32 \(compressed\) photons need min and max"):
        read_isetcam_scene(tmp_path / "bad.mat")
    scene["illuminant"]["data"] = {"photons": ill_codes.astype(np.int16), "min": lo, "max": hi}
    scipy.io.savemat(tmp_path / "bad16.mat", {"scene": scene})
    with pytest.raises(ValueError, match=r"scene\.illuminant\.data\.photons: expected numbers, or uint32 codes"):
        read_isetcam_scene(tmp_path / "bad16.mat")


def test_an_empty_illuminant_is_no_illuminant(tmp_path):
    """MATLAB's [] for illuminant.data.photons (ISETCam's illuminantGet returns [] for it: none) was refused as
    'expected 2 values (one per wavelength)'; it is a scene without an illuminant."""
    wave = np.array([[500.0, 600.0]])
    scene = _scene_struct(np.ones((2, 3, 2)), wave,
                          illuminant={"data": {"photons": np.zeros((0, 0))}, "spectrum": {"wave": np.zeros((0, 0))}})
    scipy.io.savemat(tmp_path / "e.mat", {"scene": scene})
    s = read_isetcam_scene(tmp_path / "e.mat", dtype=torch.float64)
    assert s.illuminant_photons is None and s.photons.shape == (1, 2, 2, 3)


def test_v73_hdf5_file(tmp_path):
    wave = np.array([500.0, 600.0])
    photons = np.arange(2 * 3 * 2, dtype=np.float64).reshape(2, 3, 2) * 1e14 + 1.0
    with h5py.File(tmp_path / "v73.mat", "w") as f:
        g = f.create_group("scene")
        g.create_group("data").create_dataset("photons", data=photons.T)  # MATLAB column-major on disk
        g.create_group("spectrum").create_dataset("wave", data=wave[None, :].T)
        g.create_dataset("wAngular", data=np.array([[8.0]]))
        g.create_dataset("distance", data=np.array([[3.0]]))
    s = read_isetcam_scene(tmp_path / "v73.mat", dtype=torch.float64)
    assert torch.equal(s.photons[0], torch.from_numpy(photons).permute(2, 0, 1))
    assert float(s.hfov_deg[0]) == 8.0 and float(s.distance_m[0]) == 3.0


def test_bad_files(tmp_path):
    wave = np.arange(400.0, 701.0, 100.0)
    scipy.io.savemat(tmp_path / "ok.mat", {"scene": _scene_struct(np.ones((4, 4, 4)), wave)})
    raw = (tmp_path / "ok.mat").read_bytes()
    (tmp_path / "cut.mat").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match="not a readable MATLAB"):
        read_isetcam_scene(tmp_path / "cut.mat")
    with pytest.raises(ValueError, match="variable"):
        read_isetcam_scene(tmp_path / "ok.mat", variable="oi")
    scipy.io.savemat(tmp_path / "bad.mat", {"scene": _scene_struct(np.ones((4, 4, 3)), wave)})
    with pytest.raises(ValueError, match="scene.data.photons"):
        read_isetcam_scene(tmp_path / "bad.mat")
    scipy.io.savemat(tmp_path / "neg.mat", {"scene": _scene_struct(-np.ones((2, 2, 4)), wave)})
    with pytest.raises(ValueError, match="photons"):
        read_isetcam_scene(tmp_path / "neg.mat")
    # wavelengths in micrometres loaded as a scene of 0.4-0.7 nm light (an audit of the readers)
    scipy.io.savemat(tmp_path / "um.mat", {"scene": _scene_struct(np.ones((2, 2, 4)), wave / 1000)})
    with pytest.raises(ValueError, match=r"scene.spectrum.wave: expected wavelengths in nm.*got 0.4-0.7"):
        read_isetcam_scene(tmp_path / "um.mat")


def test_malformed_fields_are_named(tmp_path):
    """Malformed optional fields name the field and the file (they gave numpy's 'axes don't match', an IndexError
    or 'could not convert string'); compressed uint8 photons without bitDepth are decoded with 8 bits (they were
    read as 16-bit: 257x too dim); dmax below dmin is refused."""
    wave = np.arange(400.0, 701.0, 100.0)
    for name, extra, message in (("ill", {"illuminant": {"data": {"photons": np.ones(7)}}},
                                  r"scene\.illuminant\.data\.photons: expected 4 values"),
                                 ("empty", {"wAngular": np.zeros((0, 0))}, r"scene\.wAngular: expected a number"),
                                 ("text", {"distance": "abc"}, r"scene\.distance: expected a number")):
        scipy.io.savemat(tmp_path / f"{name}.mat", {"scene": _scene_struct(np.ones((2, 2, 4)), wave, **extra)})
        with pytest.raises(ValueError, match=message) as err:
            read_isetcam_scene(tmp_path / f"{name}.mat")
        assert f"{name}.mat" in str(err.value)
    codes = np.array([[[0, 255, 51, 102]]], dtype=np.uint8)
    scipy.io.savemat(tmp_path / "u8.mat", {"scene": _scene_struct(codes, wave)
                                           | {"data": {"photons": codes, "dmin": 0.0, "dmax": 255e12}}})
    s = read_isetcam_scene(tmp_path / "u8.mat", dtype=torch.float64)
    np.testing.assert_allclose(s.photons[0, :, 0, 0].numpy(), codes[0, 0] * 1e12, rtol=1e-12)
    # a bitDepth the codes cannot have (ieCompressData: uint16 codes 0 .. 2^bitDepth - 1, bitDepth <= 16): 40 had
    # read code 65535 as 1.0000059e14 for dmax 1e16, 0 as NaN photons, with no word of bitDepth
    codes16 = np.array([[[0, 65535, 1, 2]]], dtype=np.uint16)
    for bits in (40.0, 0.0, 12.5):
        scipy.io.savemat(tmp_path / "bd.mat", {"scene": _scene_struct(codes16, wave) | {
            "data": {"photons": codes16, "dmin": 1e14, "dmax": 1e16, "bitDepth": bits}}})
        with pytest.raises(ValueError, match=r"scene\.data\.bitDepth: expected an integer from 1 to 16 .*bd\.mat"):
            read_isetcam_scene(tmp_path / "bd.mat")
    # complex photons were read as their real part (a warning only); a wave of text gave numpy's bare message
    scipy.io.savemat(tmp_path / "cx.mat", {"scene": _scene_struct(np.ones((2, 2, 4)) * (1e15 + 5e15j), wave)})
    with pytest.raises(ValueError, match=r"scene\.data\.photons: expected real numbers .*cx\.mat"):
        read_isetcam_scene(tmp_path / "cx.mat")
    scipy.io.savemat(tmp_path / "ws.mat", {"scene": _scene_struct(np.ones((2, 2, 1)), "five hundred")})
    with pytest.raises(ValueError, match=r"scene\.spectrum\.wave: expected numbers \(nm\) .*ws\.mat"):
        read_isetcam_scene(tmp_path / "ws.mat")
    scipy.io.savemat(tmp_path / "dmax.mat", {"scene": _scene_struct(codes, wave)
                                             | {"data": {"photons": codes, "dmin": 1.0, "dmax": 0.5}}})
    with pytest.raises(ValueError, match="scene.data.dmin, dmax: expected dmin <= dmax"):
        read_isetcam_scene(tmp_path / "dmax.mat")


def test_defaults_type_illuminant_grid_and_empty_names_are_read_as_isetcam_means_them(tmp_path):
    """io audit (2026-12-01): a scene without wAngular / distance got 10 deg / 1.2 m with no record; an optical image
    (irradiance) was read as a scene (radiance); an illuminant on 400-500 nm was attached to a 500-600 nm scene; a
    v7.3 file's empty name (MATLAB_empty) became the name '\\x00\\x00'; a descending wave named no file."""
    ph, w3 = np.ones((2, 2, 3)), np.array([500.0, 550.0, 600.0])
    scipy.io.savemat(tmp_path / "nofov.mat", {"scene": {"data": {"photons": ph}, "spectrum": {"wave": w3}}})
    s = read_isetcam_scene(tmp_path / "nofov.mat")
    assert s.metadata["defaulted"] == ["hfov_deg", "distance_m"] and float(s.hfov_deg[0]) == 10.0
    scipy.io.savemat(tmp_path / "fov.mat", {"scene": {"data": {"photons": ph}, "spectrum": {"wave": w3},
                                                      "wAngular": 4.0, "distance": 2.0}})
    assert read_isetcam_scene(tmp_path / "fov.mat").metadata["defaulted"] == []
    scipy.io.savemat(tmp_path / "oi.mat", {"oi": {"type": "opticalimage", "data": {"photons": ph},
                                                  "spectrum": {"wave": w3}}})
    with pytest.raises(ValueError, match=r"variable: 'oi' in .*oi\.mat' is an ISETCam 'opticalimage', not a scene"):
        read_isetcam_scene(tmp_path / "oi.mat", variable="oi")
    ill = {"data": {"photons": np.array([1.0, 2.0, 3.0])}, "spectrum": {"wave": np.array([400.0, 450.0, 500.0])}}
    scipy.io.savemat(tmp_path / "ill.mat", {"scene": {"data": {"photons": ph}, "spectrum": {"wave": w3},
                                                      "illuminant": ill}})
    with pytest.raises(ValueError, match=r"scene.illuminant.spectrum.wave: expected the scene's wavelengths "
                                         r"\(500-600 nm, 3\) in .*got 400-500 nm \(3\)"):
        read_isetcam_scene(tmp_path / "ill.mat")
    ill["spectrum"]["wave"] = w3  # on the scene's grid: attached
    scipy.io.savemat(tmp_path / "ill_ok.mat", {"scene": {"data": {"photons": ph}, "spectrum": {"wave": w3},
                                                         "illuminant": ill}})
    assert read_isetcam_scene(tmp_path / "ill_ok.mat").illuminant_photons[0].tolist() == [1.0, 2.0, 3.0]
    with h5py.File(tmp_path / "empty_name.mat", "w") as f:
        g = f.create_group("scene")
        g.create_group("data").create_dataset("photons", data=ph.T)
        g.create_group("spectrum").create_dataset("wave", data=w3[None, :].T)
        name = g.create_dataset("name", data=np.array([0, 0], dtype=np.uint64))  # MATLAB's '' in a v7.3 file
        name.attrs["MATLAB_class"] = np.bytes_(b"char")
        name.attrs["MATLAB_empty"] = np.uint8(1)
    assert read_isetcam_scene(tmp_path / "empty_name.mat").name == "empty_name"
    v5 = {"scene": {"name": "", "data": {"photons": ph}, "spectrum": {"wave": w3}}}
    scipy.io.savemat(tmp_path / "empty_v5.mat", v5)
    assert read_isetcam_scene(tmp_path / "empty_v5.mat").name == "empty_v5"  # (it was named '[]')
    scipy.io.savemat(tmp_path / "down.mat", {"scene": {"data": {"photons": ph}, "spectrum": {"wave": w3[::-1]}}})
    with pytest.raises(ValueError, match=r"path: .*down\.mat': wavelengths_nm: expected a strictly increasing"):
        read_isetcam_scene(tmp_path / "down.mat")


def test_a_parity_case_written_without_its_suffix_reads_back(tmp_path):
    from isettorch.io.isetcam import read_parity_case, write_parity_case

    write_parity_case(tmp_path / "mycase", {"a": np.ones(2)})  # (np.savez wrote mycase.npz)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mycase"]
    assert read_parity_case(tmp_path / "mycase", check=False)["a"].tolist() == [1.0, 1.0]


def test_an_illuminant_grid_in_single_precision_is_the_scenes_and_an_empty_type_is_none(tmp_path):
    """The illuminant-grid check (1e-6 nm) refused a grid stored in single precision or rounded to 0.01 nm; an empty
    type field read as an ISETCam '[]' type (review of 2026-12-01)."""
    w = np.linspace(398.29, 1001.39, 61)
    ph = np.ones((2, 2, 61))
    ill = {"data": {"photons": np.ones(61)}, "spectrum": {"wave": w.astype(np.float32).astype(np.float64).round(2)}}
    scipy.io.savemat(tmp_path / "f32.mat", {"scene": {"type": "", "data": {"photons": ph}, "spectrum": {"wave": w},
                                                      "illuminant": ill}})
    s = read_isetcam_scene(tmp_path / "f32.mat")
    assert s.illuminant_photons.shape[-1] == 61


def test_an_illuminant_on_a_shifted_grid_is_refused(tmp_path):
    """A grid 1 nm off the scene's (10 nm spacing) is another grid: refused, naming how far off."""
    w = np.arange(400.0, 701.0, 10.0)
    ill = {"data": {"photons": np.ones(w.size)}, "spectrum": {"wave": w + 1.0}}
    scipy.io.savemat(tmp_path / "shift.mat", {"scene": {"data": {"photons": np.ones((2, 2, w.size))},
                                                        "spectrum": {"wave": w}, "illuminant": ill}})
    with pytest.raises(ValueError, match=r"scene.illuminant.spectrum.wave: .*up to 1 nm off"):
        read_isetcam_scene(tmp_path / "shift.mat")


def test_photons_beyond_the_dtypes_range_name_the_dtype(tmp_path):
    # A finite float64 file of 1e40 photons was refused as holding 'NaN/Inf entries' (float32's overflow).
    p = tmp_path / "big.mat"
    scipy.io.savemat(p, {"scene": _scene_struct(np.full((2, 3, 4), 1e40), np.arange(400.0, 701.0, 100.0))})
    with pytest.raises(ValueError, match=r"dtype: .*big.mat' holds photons up to 1e\+40, beyond torch.float32"):
        read_isetcam_scene(p)
    assert float(read_isetcam_scene(p, dtype=torch.float64).photons.max()) == 1e40


def test_a_negative_or_nan_illuminant_is_refused_spatially_varying_too(tmp_path):
    # A spatially varying illuminant (rows, cols, wave), kept as metadata['illuminant_photons_map'], was not checked:
    # -5 photons was accepted.
    wave = np.array([400.0, 500.0, 600.0])
    photons = np.ones((2, 3, 3))
    for name, ill in (("map", -5 * np.ones((2, 3, 3))), ("nan", np.array([1.0, np.nan, 2.0]))):
        p = tmp_path / f"{name}.mat"
        scipy.io.savemat(p, {"scene": _scene_struct(photons, wave, illuminant={"data": {"photons": ill},
                                                                               "spectrum": {"wave": wave}})})
        with pytest.raises(ValueError, match=rf"scene.illuminant.data.photons: expected finite non-negative .*{name}"):
            read_isetcam_scene(p)
    ok = tmp_path / "ok.mat"
    scipy.io.savemat(ok, {"scene": _scene_struct(photons, wave, illuminant={"data": {"photons": 2 * np.ones((2, 3, 3))},
                                                                            "spectrum": {"wave": wave}})})
    assert float(read_isetcam_scene(ok).metadata["illuminant_photons_map"].min()) == 2.0
