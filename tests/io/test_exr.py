"""Spectral OpenEXR (Fichet et al. 2021): exact float32 round trip, channel names seen by OpenEXR itself."""

import numpy as np
import OpenEXR
import pytest
import torch

from isettorch import spectral
from isettorch.io import read_scene_exr, read_spectral_exr, write_scene_exr, write_spectral_exr
from isettorch.io.exr import channel_name, parse_channel_name
from isettorch.scene import Scene


def test_round_trip_is_exact_and_openexr_sees_documented_channels(tmp_path):
    rng = np.random.default_rng(0)
    data = (rng.random((4, 5, 7)) * 10 ** rng.uniform(-3, 3, (4, 5, 7))).astype(np.float32)
    w = [450.0, 500.0, 550.5, 600.25]
    p = write_spectral_exr(tmp_path / "a.exr", data, w)
    back, w_back, header = read_spectral_exr(p)
    assert back.dtype == torch.float32 and np.array_equal(back.numpy(), data)
    assert w_back.tolist() == w
    f = OpenEXR.File(str(p))  # the OpenEXR package's own reader
    names = sorted(f.channels())
    assert names == ["S0.450,000000nm", "S0.500,000000nm", "S0.550,500000nm", "S0.600,250000nm"]
    assert f.header()["spectralLayoutVersion"] == "1.0"
    assert f.header()["emissiveUnits"] == "W.m^-2.sr^-1"
    assert np.array_equal(f.channels()["S0.550,500000nm"].pixels, data[2])


def test_scene_round_trip_keeps_radiance_and_metadata(tmp_path):
    w = torch.arange(400.0, 701.0, 50.0)
    g = torch.Generator().manual_seed(0)
    photons = torch.rand(2, w.numel(), 6, 8, generator=g) * 1e16
    ill = torch.rand(2, w.numel(), generator=g) * 1e16
    scene = Scene(photons, w, name="rt", hfov_deg=[12.5, 3.0], distance_m=[2.0, 5.0], illuminant_photons=ill)
    p = write_scene_exr(tmp_path / "s.exr", scene, index=1)
    # stored channels are the float32 spectral radiance in W/sr/m^2/nm
    stored = OpenEXR.File(str(p)).channels()["S0.450,000000nm"].pixels
    energy = spectral.photons_to_energy(photons[1].double(), w.double(), dim=0)[1].float().numpy()
    assert np.array_equal(stored, energy)
    back = read_scene_exr(p)
    torch.testing.assert_close(back.photons, photons[1:2], rtol=1e-6, atol=0)
    assert float(back.hfov_deg[0]) == pytest.approx(3.0) and float(back.distance_m[0]) == pytest.approx(5.0)
    torch.testing.assert_close(back.illuminant_photons, ill[1:2], rtol=1e-6, atol=0)
    assert back.metadata["defaulted"] == []


def test_channel_names_and_units():
    assert channel_name(550) == "S0.550,000000nm"
    assert channel_name(412.5, "T") == "T.412,500000nm"
    assert parse_channel_name("S0.550,000000nm") == ("S0", 550.0)
    assert parse_channel_name("T.0,55um")[1] == pytest.approx(550.0)
    # frequency: c / 545.0771 THz = 550 nm
    assert parse_channel_name("S0.545,0771THz")[1] == pytest.approx(550.0, rel=1e-6)
    assert parse_channel_name("R") is None and parse_channel_name("S0.abcnm") is None


def test_corrupt_truncated_and_non_spectral_files(tmp_path):
    p = write_spectral_exr(tmp_path / "a.exr", np.ones((3, 16, 16), np.float32), [500.0, 550.0, 600.0])
    raw = p.read_bytes()
    (tmp_path / "cut.exr").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(ValueError, match="not a readable OpenEXR"):
        read_spectral_exr(tmp_path / "cut.exr")
    (tmp_path / "junk.exr").write_bytes(b"not an exr file at all" * 10)
    with pytest.raises(ValueError, match="not a readable OpenEXR"):
        read_spectral_exr(tmp_path / "junk.exr")
    rgb = {c: np.zeros((4, 4), np.float32) for c in "RGB"}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, rgb).write(str(tmp_path / "rgb.exr"))
    with pytest.raises(ValueError, match="no spectral channels"):
        read_spectral_exr(tmp_path / "rgb.exr")
    with pytest.raises(ValueError, match="wavelengths_nm"):
        write_spectral_exr(tmp_path / "b.exr", np.ones((2, 4, 4), np.float32), [500.0])
    with pytest.raises(ValueError, match="no such file"):
        read_spectral_exr(tmp_path / "missing.exr")


def test_scene_batch_writes_every_sample_or_refuses(tmp_path):
    # Friction 12 of issue 18: a batch used to be written as its sample 0 only, silently.
    w = torch.arange(400.0, 701.0, 100.0)
    photons = torch.rand(3, w.numel(), 4, 5, generator=torch.Generator().manual_seed(1)) * 1e16
    scene = Scene(photons, w, hfov_deg=[10.0, 11.0, 12.0])
    with pytest.raises(ValueError, match=r"a batch of 3.*\{i\}"):
        write_scene_exr(tmp_path / "s.exr", scene)
    paths = write_scene_exr(tmp_path / "s_{i:02d}.exr", scene)
    assert [p.name for p in paths] == ["s_00.exr", "s_01.exr", "s_02.exr"]
    for i, p in enumerate(paths):
        back = read_scene_exr(p)
        torch.testing.assert_close(back.photons, photons[i:i + 1], rtol=1e-6, atol=0)
        assert float(back.hfov_deg[0]) == pytest.approx(10.0 + i)
    with pytest.raises(ValueError, match="index"):
        write_scene_exr(tmp_path / "x.exr", scene, index=3)


def test_scene_exr_with_bad_contents_names_the_file(tmp_path):
    """Negative radiance and an illuminant attribute of the wrong length are errors naming the file (they named
    internal arguments, 'photons' with a converted value and 'energy')."""
    from isettorch.scene import uniform

    scene = uniform(size=4, dtype=torch.float64)
    p = write_scene_exr(tmp_path / "s.exr", scene)
    data, w, _ = read_spectral_exr(p)
    bad = write_spectral_exr(tmp_path / "neg.exr", -data.numpy().astype(np.float32), w.numpy(), component="S0")
    with pytest.raises(ValueError, match=r"path: .*neg\.exr.* negative or non-finite radiance"):
        read_scene_exr(bad)
    # complex data were written as their real part (a warning only); wavelengths as text gave torch's own message,
    # and an increasing grid held in a reversed NumPy view was refused with it
    with pytest.raises(ValueError, match="data: expected real values"):
        write_spectral_exr(tmp_path / "cx.exr", data.numpy() * (1 + 1j), w.numpy())
    with pytest.raises(TypeError, match="wavelengths_nm: expected a number or tensor"):
        write_spectral_exr(tmp_path / "txt.exr", data.numpy(), [str(v) for v in w.tolist()])
    back, w2, _ = read_spectral_exr(write_spectral_exr(tmp_path / "view.exr", data.numpy(),
                                                       w.numpy()[::-1].copy()[::-1]))
    assert torch.equal(w2, w) and torch.equal(back, data)


def test_values_a_float32_file_cannot_hold_are_refused_not_written(tmp_path):
    """The writer checked finiteness before the float32 cast: 1e40 was written as inf (a file its reader refuses)
    and 1e-50 as 0, silently; both are errors naming the data, and nothing is written."""
    for value, what in ((1e40, "overflow float32"), (1e-50, "underflow to 0 in float32")):
        with pytest.raises(ValueError, match=f"data: .*{what}"):
            write_spectral_exr(tmp_path / "x.exr", np.full((2, 2, 2), value), [500.0, 600.0])
        assert not (tmp_path / "x.exr").exists()
    tiny = np.full((2, 2, 2), 1e-44)  # a float32 subnormal: kept (nonzero)
    back, _, _ = read_spectral_exr(write_spectral_exr(tmp_path / "s.exr", tiny, [500.0, 600.0]))
    assert (back > 0).all()


def test_a_scene_in_other_radiance_units_is_refused(tmp_path):
    """read_scene_exr recorded emissiveUnits but read a file in mW.m^-2.sr^-1 as W (1000x too bright)."""
    w = torch.tensor([500.0, 600.0])
    data = torch.full((2, 3, 4), 0.01)
    ok = write_spectral_exr(tmp_path / "w.exr", data, w)
    assert read_scene_exr(ok).photons.shape == (1, 2, 3, 4)
    per_nm = write_spectral_exr(tmp_path / "nm.exr", data, w, attributes={"emissiveUnits": "W.m^-2.sr^-1.nm^-1 "})
    assert torch.equal(read_scene_exr(per_nm).photons, read_scene_exr(ok).photons)  # tinyexr's spelling
    mw = write_spectral_exr(tmp_path / "mw.exr", data, w, attributes={"emissiveUnits": "mW.m^-2.sr^-1"})
    with pytest.raises(ValueError, match=r"gives its radiance in 'mW.m\^-2.sr\^-1'; expected 'W.m\^-2.sr\^-1'"):
        read_scene_exr(mw)


@pytest.mark.parametrize("wavelengths, match", [([5e-7, 6e-7], r"expected wavelengths in nm, got 5e-07-6e-07"),
                                                ([0.45, 0.55], r"expected wavelengths in nm, got 0.45-0.55"),
                                                ([float("nan")], "wavelengths_nm"), ([-550.0], "wavelengths_nm"),
                                                # the reader returns bands increasing: a per-band attribute (the
                                                # illuminant) written 700, 550, 400 came back out of step with them
                                                ([700.0, 550.0, 400.0], r"expected increasing wavelengths")])
def test_spectral_exr_refuses_wavelengths_that_are_not_nanometres(tmp_path, wavelengths, match):
    """Metres and micrometres were written as channels of 0-1 nm; NaN or negative ones as names its reader refuses."""
    with pytest.raises(ValueError, match=match):
        write_spectral_exr(tmp_path / "w.exr", np.ones((len(wavelengths), 2, 2), np.float32), wavelengths)
    assert not (tmp_path / "w.exr").exists()


def test_reading_refuses_channels_not_in_nanometres_or_at_one_wavelength_twice(tmp_path):
    # Channels 'S0.0,400000nm' (micrometres written as nm) loaded a scene of 0.4-0.7 nm light, 1000x too few photons;
    # 'S0.550nm' beside 'S0.550,000000nm' gave the grid [550, 550, 600], refused later naming no file.
    px = np.ones((2, 2), np.float32)
    um = {f"S0.0,{w}nm": px for w in ("400000", "550000", "700000")}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, um).write(str(tmp_path / "um.exr"))
    with pytest.raises(ValueError, match=r"um.exr.*S0 channels: expected wavelengths in nm, got 0.4-0.7"):
        read_scene_exr(tmp_path / "um.exr")
    dup = {"S0.550nm": px, "S0.550,000000nm": px, "S0.600nm": px}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, dup).write(str(tmp_path / "dup.exr"))
    with pytest.raises(ValueError, match=r"dup.exr' has two S0 channels at one wavelength"):
        read_spectral_exr(tmp_path / "dup.exr")


def test_a_data_window_other_than_the_display_window_or_several_parts_are_refused(tmp_path):
    """A 3 x 4 data window at (2, 1) of an 8 x 6 display window came back as a 3 x 4 image (its place dropped), and
    a multi-part file as its part 0 alone; both are refused naming the file. Equal windows read as before."""
    from isettorch.io import read_image

    ones = np.ones((3, 4), np.float32)
    chans = {c: ones for c in "RGB"}
    header = {"type": OpenEXR.scanlineimage,
              "dataWindow": (np.array([2, 1], np.int32), np.array([5, 3], np.int32)),
              "displayWindow": (np.array([0, 0], np.int32), np.array([7, 5], np.int32))}
    OpenEXR.File(header, chans).write(str(tmp_path / "crop.exr"))
    with pytest.raises(ValueError, match=r"crop\.exr' has a data window \(2, 1\)-\(5, 3\) that is not its display "
                                         r"window \(0, 0\)-\(7, 5\)"):
        read_image(tmp_path / "crop.exr")
    parts = [OpenEXR.Part({"type": OpenEXR.scanlineimage}, chans, name) for name in ("a", "b")]
    OpenEXR.File(parts).write(str(tmp_path / "two.exr"))
    with pytest.raises(ValueError, match=r"two\.exr' is a multi-part OpenEXR file \(2 parts\)"):
        read_image(tmp_path / "two.exr")
    OpenEXR.File({"type": OpenEXR.scanlineimage}, chans).write(str(tmp_path / "plain.exr"))
    assert read_image(tmp_path / "plain.exr").shape == (1, 3, 3, 4)


def test_a_scene_illuminant_beyond_float32_is_refused_not_written_as_inf(tmp_path):
    """The illuminant attribute was cast to float32 unchecked: 1e60 photons were written as inf (the radiance
    itself is checked); refused naming it, and no file is written."""
    w = torch.tensor([500.0, 600.0], dtype=torch.float64)
    s = Scene(torch.full((1, 2, 2, 2), 1e15, dtype=torch.float64), w,
              illuminant_photons=torch.tensor([1e60, 1e15], dtype=torch.float64))
    with pytest.raises(ValueError, match=r"scene\.illuminant_photons: values up to .* overflow float32"):
        write_scene_exr(tmp_path / "ill.exr", s)
    assert not (tmp_path / "ill.exr").exists()
