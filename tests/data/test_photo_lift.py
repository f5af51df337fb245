"""The photo lifter (isettorch.data.photos.lift_srgb) against colour-science, and its wavelength argument."""

import colour
import numpy as np
import pytest
import torch

from isettorch.data.photos import PhotoSceneDataset, lift_srgb


def _roundtrip_de2000(codes: np.ndarray, grid) -> np.ndarray:
    """dE2000 between 8-bit sRGB colours and their lifted reflectances seen under D65 by the CIE 1931 observer on
    the lift's grid (colour-science's CMFs and illuminant, white normalised by Y; an independent rendering)."""
    lifted = lift_srgb(codes[None], grid)
    wl = lifted["wavelengths_nm"].numpy()
    refl = lifted["maps"][:, 0].numpy().T @ lifted["reflectance"].numpy()  # [N, L]
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    xbar = np.stack([np.interp(wl, cmfs.wavelengths, cmfs.values[:, i]) for i in range(3)], 1)
    d65 = colour.SDS_ILLUMINANTS["D65"]
    e = np.interp(wl, d65.wavelengths, d65.values)
    xyz = (refl * e) @ xbar / (e @ xbar[:, 1])
    white_xy = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    lab = colour.XYZ_to_Lab(xyz, white_xy)
    ref = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(codes / 255.0), white_xy)
    return colour.delta_E(lab, ref, method="CIE 2000")


def test_lift_round_trip_on_the_configs_grid_is_within_its_stated_error():
    # every 8-bit colour in steps of 15 (and 255), the docstring's bound on the configs' 400:10:700 nm grid
    v = np.r_[np.arange(0, 256, 15), 255]
    codes = np.stack(np.meshgrid(v, v, v, indexing="ij"), -1).reshape(-1, 3).astype(np.uint8)
    de = _roundtrip_de2000(codes, (400.0, 700.0, 10.0))
    assert de.max() <= 0.73 and de.mean() <= 0.25
    # on the basis' own range the round trip is exact up to its sampling
    assert _roundtrip_de2000(codes, (380.0, 780.0, 5.0)).max() < 0.05


def test_wavelengths_are_a_range_or_a_tensor_never_misread():
    img = np.full((4, 4, 3), 128, np.uint8)
    assert lift_srgb(img, (400.0, 700.0, 10.0))["wavelengths_nm"].numel() == 31
    assert lift_srgb(img, np.array([400.0, 700.0, 10.0]))["wavelengths_nm"].numel() == 31
    three = torch.tensor([450.0, 550.0, 650.0], dtype=torch.float64)
    assert torch.equal(lift_srgb(img, three)["wavelengths_nm"], three)
    # three wavelengths as a list were read as (start, stop, step): a one-sample grid
    for bad in ([450.0, 550.0, 650.0], np.arange(400.0, 701.0, 10.0), (700.0, 400.0, 10.0), (400.0, 700.0, 0.0),
                (400.0, 700.0, -10.0), (300.0, 370.0, 10.0), torch.tensor([300.0, 800.0]), "400-700"):
        with pytest.raises(ValueError, match="wavelengths_nm"):
            lift_srgb(img, bad)
    # a grid reaching beyond the basis (a design's 370-700 nm): 0 reflectance there, the rest lifted
    wide = lift_srgb(img, (370.0, 700.0, 10.0))
    assert float(wide["reflectance"][:, 0].abs().max()) == 0.0 and float(wide["reflectance"][:, 1:].min()) > 0


def test_photo_dataset_reads_its_grid_the_same_way(tmp_path):
    from PIL import Image

    Image.fromarray(np.full((8, 8, 3), 100, np.uint8)).save(tmp_path / "a.png")
    assert PhotoSceneDataset(tmp_path, 4, wavelengths_nm=(400.0, 700.0, 10.0)).wl.numel() == 31
    with pytest.raises(ValueError, match="wavelengths_nm"):
        PhotoSceneDataset(tmp_path, 4, wavelengths_nm=[450.0, 550.0, 650.0])


def test_photo_dataset_checks_its_illuminant_weights(tmp_path):
    """'candle', a zero or NaN weight built a dataset that failed at ds[0] naming 'kind' or 'weights'; a negative
    weight was read as 0. Each is now refused at construction naming illuminants, as natural_config refuses them."""
    from PIL import Image

    Image.fromarray(np.full((8, 8, 3), 100, np.uint8)).save(tmp_path / "a.png")
    for bad, said in (({"candle": 1}, "'candle': unknown kind"), ({"daylight": 0}, "positive sum"),
                      ({"daylight": float("nan")}, "non-negative weights"),
                      ({"daylight": -1, "led": 1}, "non-negative"), ([1], "expected a dict")):
        with pytest.raises(ValueError, match=rf"^illuminants: .*{said}"):
            PhotoSceneDataset(tmp_path, 4, illuminants=bad)
    ds = PhotoSceneDataset(tmp_path, 4, illuminants={"led": 1})
    assert ds[0]["meta"]["illuminants"][0].startswith("led")


def test_lift_refuses_integer_tensors_and_empty_images():
    # A uint8 tensor of codes 0 and 1 passed the [0, 1] check as values (code 1 lifted as white, 1.0, for the
    # numpy array's 3.04e-4 = (1/255) / 12.92, IEC 61966-2-1); a bool mask too; an empty image returned empty maps.
    from isettorch.data.photos import lift_srgb

    codes = np.ones((4, 4, 3), np.uint8)
    assert float(lift_srgb(codes)["maps"].max()) == pytest.approx(1 / 255 / 12.92, rel=1e-9)
    for bad in (torch.from_numpy(codes).permute(2, 0, 1), torch.ones(3, 4, 4, dtype=torch.bool)):
        with pytest.raises(TypeError, match=r"image: expected encoded sRGB floats .* got a torch\.(uint8|bool) tensor"):
            lift_srgb(bad)
    with pytest.raises(ValueError, match="image: expected encoded sRGB"):
        lift_srgb(torch.zeros(3, 0, 4))
