"""CAVE (PNG per band), KAIST (EXR) and ICVL / ARAD (MATLAB v7.3 via h5py) loaders on small files."""

import h5py
import numpy as np
import OpenEXR
import pytest
import torch
from PIL import Image

from isettorch import spectral
from isettorch.io import load_arad, load_cave, load_icvl, load_kaist


def _write_cave(folder, refl16):
    d = folder / "toy_ms" / "toy_ms"
    d.mkdir(parents=True)
    for k in range(refl16.shape[0]):
        Image.fromarray(refl16[k]).save(d / f"toy_ms_{k + 1:02d}.png")
    return folder / "toy_ms"


def test_cave_reflectance_under_d65(tmp_path):
    rng = np.random.default_rng(0)
    refl16 = rng.integers(1000, 65535, size=(31, 6, 5), dtype=np.uint16)
    root = _write_cave(tmp_path, refl16)
    s = load_cave(root, dtype=torch.float64)
    assert s.photons.shape == (1, 31, 6, 5) and s.wavelengths_nm[0] == 400 and s.wavelengths_nm[-1] == 700
    np.testing.assert_allclose(s.reflectance()[0].numpy(), refl16 / 65535.0, rtol=1e-10)
    assert float(s.mean_luminance()) == pytest.approx(100.0)
    # the illuminant is D65 (relative, in photons)
    d65 = spectral.energy_to_photons(spectral.illuminant("D65", s.wavelengths_nm), s.wavelengths_nm, dim=0)
    ratio = s.illuminant_photons[0] / d65
    assert float(ratio.max() / ratio.min()) == pytest.approx(1.0, abs=1e-9)


def test_cave_errors(tmp_path):
    refl16 = np.full((31, 4, 4), 30000, dtype=np.uint16)
    root = _write_cave(tmp_path, refl16)
    band = root / "toy_ms" / "toy_ms_07.png"
    raw = band.read_bytes()
    band.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match="toy_ms_07.png"):
        load_cave(root)
    band.unlink()
    with pytest.raises(ValueError, match="consecutive"):
        load_cave(root)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no CAVE band"):
        load_cave(tmp_path / "empty")
    with pytest.raises(ValueError, match="no such directory"):
        load_cave(tmp_path / "missing")


def test_kaist_exr(tmp_path):
    rng = np.random.default_rng(1)
    cube = rng.random((4, 3, 5)).astype(np.float32) + 0.1
    names = ["w420nm", "w430nm", "w440nm", "w450nm"]
    chans = {n: cube[i] for i, n in enumerate(names)}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {n: chans[n] for n in reversed(names)}).write(
        str(tmp_path / "k.exr"))
    s = load_kaist(tmp_path / "k.exr", dtype=torch.float64)
    assert s.wavelengths_nm.tolist() == [420.0, 430.0, 440.0, 450.0]
    # radiance (energy) -> photons, then one scale factor for the whole scene
    e = spectral.photons_to_energy(s.photons[0], s.wavelengths_nm, dim=0).numpy()
    k = e / cube
    assert k.max() / k.min() == pytest.approx(1.0, abs=1e-6)
    (tmp_path / "bad.exr").write_bytes(b"\x76\x2f\x31\x01" + b"\x00" * 20)
    with pytest.raises(ValueError, match="not a readable OpenEXR"):
        load_kaist(tmp_path / "bad.exr")


@pytest.mark.parametrize("key,loader", [("rad", load_icvl), ("cube", load_arad)])
def test_icvl_arad_v73(tmp_path, key, loader):
    rng = np.random.default_rng(2)
    cube = rng.random((6, 4, 3)) + 0.05  # MATLAB order (rows, cols, bands)
    bands = np.array([400.0, 450.0, 500.0])
    with h5py.File(tmp_path / "f.mat", "w", userblock_size=512) as f:  # v7.3 files are HDF5 with a userblock
        f.create_dataset(key, data=cube.T)  # HDF5 holds MATLAB arrays transposed: (bands, cols, rows)
        f.create_dataset("bands", data=bands[None, :].T)
    s = loader(tmp_path / "f.mat", dtype=torch.float64)
    assert s.photons.shape == (1, 3, 6, 4)
    e = spectral.photons_to_energy(s.photons[0], s.wavelengths_nm, dim=0).numpy()
    k = e / np.transpose(cube, (2, 0, 1))
    assert k.max() / k.min() == pytest.approx(1.0, abs=1e-9)
    assert s.wavelengths_nm.tolist() == bands.tolist()
    # the files hold no geometry: ISETCam's 10 deg and 1.2 m, recorded as defaulted (as the EXR and .mat readers
    # record theirs; they were not), or the caller's
    assert s.metadata["defaulted"] == ["hfov_deg", "distance_m"]
    assert float(s.hfov_deg) == 10.0 and float(s.distance_m) == 1.2
    given = loader(tmp_path / "f.mat", hfov_deg=20.0, distance_m=3.0, dtype=torch.float64)
    assert given.metadata["defaulted"] == [] and float(given.hfov_deg) == 20.0 and float(given.distance_m) == 3.0


def test_icvl_errors(tmp_path):
    with h5py.File(tmp_path / "f.mat", "w") as f:
        f.create_dataset("rad", data=np.ones((3, 4, 5)))
    raw = (tmp_path / "f.mat").read_bytes()
    (tmp_path / "cut.mat").write_bytes(raw[: len(raw) // 3])
    with pytest.raises(ValueError, match="not a readable"):
        load_icvl(tmp_path / "cut.mat")
    with h5py.File(tmp_path / "other.mat", "w") as f:
        f.create_dataset("foo", data=np.ones((3, 4, 5)))
    with pytest.raises(ValueError, match="rad"):
        load_icvl(tmp_path / "other.mat")
    # without 'bands': 31 bands are ICVL's 400:10:700 nm; any other count is an error (519 became 400-5580 nm)
    for n in (31, 519):
        with h5py.File(tmp_path / f"nobands{n}.mat", "w") as f:
            f.create_dataset("rad", data=np.ones((n, 4, 6)))
    assert load_icvl(tmp_path / "nobands31.mat").wavelengths_nm.tolist() == list(np.arange(400.0, 701.0, 10.0))
    with pytest.raises(ValueError, match="bands: .* has 519 bands, not the 31"):
        load_icvl(tmp_path / "nobands519.mat")


def test_cave_needs_its_31_bands_and_reads_16_bits_as_16_bits(tmp_path):
    """A partial copy (3 bands) loaded as a 400-420 nm scene; a dark 16-bit band (max <= 255) would have been
    divided by 255 where Pillow reads 16-bit PNGs as mode I (the bit depth is the file's, not the data's)."""
    dark = np.full((31, 4, 4), 200, dtype=np.uint16)
    s = load_cave(_write_cave(tmp_path / "dark", dark), dtype=torch.float64)
    np.testing.assert_allclose(s.reflectance()[0].numpy(), 200 / 65535.0, rtol=1e-10)
    with pytest.raises(ValueError, match=r"expected consecutive CAVE bands 01..31"):
        load_cave(_write_cave(tmp_path / "part", dark[:3]))


def test_cave_bands_stored_as_16_bit_rgb_keep_their_16_bits(tmp_path):
    """A few CAVE bands are stored as RGB(A) with equal channels; at 16 bits Pillow decoded them to 8 bits (a
    code of 200 of 65535 read as 0, the band black). pypng reads them at the file's depth, as a grey band."""
    import png

    dark = np.full((31, 4, 4), 200, dtype=np.uint16)
    root = _write_cave(tmp_path, dark)
    for band, alpha in ((3, False), (9, True)):
        rgb = np.repeat(np.full((4, 4, 1), 200 * (band + 1), dtype=np.uint16), 4 if alpha else 3, axis=-1)
        if alpha:
            rgb[..., 3] = 65535
        with open(root / "toy_ms" / f"toy_ms_{band:02d}.png", "wb") as fh:
            png.Writer(4, 4, greyscale=False, alpha=alpha, bitdepth=16).write(fh, rgb.reshape(4, -1))
    r = load_cave(root, dtype=torch.float64).reflectance()[0].numpy()
    np.testing.assert_allclose(r[2], 800 / 65535.0, rtol=1e-10)
    np.testing.assert_allclose(r[8], 2000 / 65535.0, rtol=1e-10)
    np.testing.assert_allclose(r[0], 200 / 65535.0, rtol=1e-10)


def test_kaist_takes_only_wavelength_names(tmp_path):
    """Any channel with a number in 300-1100 was a band: 'frame_0512' became 512 nm."""
    chans = {"frame_0512": np.ones((2, 2), np.float32), "w420nm": np.ones((2, 2), np.float32),
             "430": np.ones((2, 2), np.float32)}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, chans).write(str(tmp_path / "k.exr"))
    assert load_kaist(tmp_path / "k.exr").wavelengths_nm.tolist() == [420.0, 430.0]


def test_kaist_keeps_bands_beyond_300_to_1100_nm(tmp_path):
    """Channels '1000' ... '1200' loaded as 1000-1100 nm: bands outside 300-1100 nm were dropped without a word
    (the Fichet layout's were kept). Every band named by a wavelength is read; a channel of micrometres is refused."""
    chans = {str(w): np.full((2, 2), w / 1000, np.float32) for w in (1000, 1050, 1100, 1150, 1200)}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, chans).write(str(tmp_path / "nir.exr"))
    s = load_kaist(tmp_path / "nir.exr", mean_luminance_cd_m2=None, dtype=torch.float64)
    assert s.wavelengths_nm.tolist() == [1000.0, 1050.0, 1100.0, 1150.0, 1200.0]
    chans = {"0.42": np.ones((2, 2), np.float32), "0.43": np.ones((2, 2), np.float32)}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, chans).write(str(tmp_path / "um.exr"))
    with pytest.raises(ValueError, match=r"expected wavelengths in nm, got 0.42-0.43"):
        load_kaist(tmp_path / "um.exr")


def test_bands_in_micrometres_are_refused(tmp_path):
    """ICVL-like bands of 0.4-0.7 (micrometres) read "the scene is black", or as a 0.4 nm scene unscaled."""
    with h5py.File(tmp_path / "um.mat", "w") as f:
        f.create_dataset("rad", data=np.random.default_rng(0).random((3, 4, 31)).T)
        f.create_dataset("bands", data=(np.arange(400.0, 701.0, 10.0) / 1000)[None, :].T)
    for scale in (100.0, None):
        with pytest.raises(ValueError, match=r"bands .*um\.mat'\): expected wavelengths in nm, got 0.4-0.7"):
            load_icvl(tmp_path / "um.mat", mean_luminance_cd_m2=scale)


def test_cave_reads_upper_case_names_skips_macos_copies_and_refuses_colour_bands(tmp_path):
    """'toy_ms_01.PNG' was 'holds no CAVE band images' (a case-sensitive glob, though the band names match in any
    case); an unzipped archive's __MACOSX/'._toy_ms_NN.png' resource forks doubled every band number; an RGB band
    whose channels differ was read as its red channel."""
    import shutil

    import png

    dark = np.full((31, 4, 4), 200, dtype=np.uint16)
    root = _write_cave(tmp_path / "up", dark)
    for f in sorted((root / "toy_ms").glob("*.png")):
        f.rename(f.with_suffix(".PNG"))
    np.testing.assert_allclose(load_cave(root, dtype=torch.float64).reflectance()[0].numpy(), 200 / 65535, rtol=1e-10)
    root = _write_cave(tmp_path / "mac", dark)
    forks = root / "__MACOSX" / "toy_ms"
    forks.mkdir(parents=True)
    for k in range(1, 32):
        (forks / f"._toy_ms_{k:02d}.png").write_bytes(b"\x00\x05\x16\x07" + b"\0" * 80)
        shutil.copy(root / "toy_ms" / f"toy_ms_{k:02d}.png", forks / f"toy_ms_{k:02d}.png")
    assert load_cave(root, dtype=torch.float64).photons.shape == (1, 31, 4, 4)
    rgb = np.stack([np.full((4, 4), 200), np.full((4, 4), 300), np.full((4, 4), 200)], -1).astype(np.uint16)
    with open(root / "toy_ms" / "toy_ms_05.png", "wb") as fh:
        png.Writer(4, 4, greyscale=False, bitdepth=16).write(fh, rgb.reshape(4, -1))
    with pytest.raises(ValueError, match=r"toy_ms_05\.png': a CAVE band stored as RGB has equal channels"):
        load_cave(root)
