"""Users' images: PNG 8/16-bit, TIFF, EXR; sRGB-encoded integer files, linear float files (issue 18, friction 12).

Files written here are read back with independent readers (Pillow, tifffile, OpenEXR) and the sRGB curve is
checked against colour-science."""

import warnings

import colour
import numpy as np
import OpenEXR
import pytest
import tifffile
import torch
from PIL import Image

from isettorch.io import read_image, write_image


def _ramp(c=3, h=5, w=7):
    g = torch.Generator().manual_seed(0)
    return torch.rand(c, h, w, generator=g, dtype=torch.float64)


def test_png_8bit_is_srgb_encoded(tmp_path):
    lin = _ramp()
    (p,) = write_image(tmp_path / "a.png", lin)
    stored = np.asarray(Image.open(p))  # independent reader
    expect = np.round(colour.cctf_encoding(lin.permute(1, 2, 0).numpy(), function="sRGB") * 255)
    assert stored.dtype == np.uint8 and np.array_equal(stored, expect.astype(np.uint8))
    back = read_image(p)
    assert back.shape == (1, 3, 5, 7) and back.dtype == torch.float32
    np.testing.assert_allclose(back[0].double().numpy(), colour.cctf_decoding(stored / 255, function="sRGB")
                               .transpose(2, 0, 1), atol=1e-6)
    # linear 0.5 is code 188 (sRGB(0.5) = 0.7354); 'linear' stores and reads code values as they are
    (q,) = write_image(tmp_path / "half.png", torch.full((3, 2, 2), 0.5))
    assert np.asarray(Image.open(q))[0, 0, 0] == 188
    (r,) = write_image(tmp_path / "lin.png", torch.full((3, 2, 2), 0.5), encoding="linear")
    assert np.asarray(Image.open(r))[0, 0, 0] == 128
    assert float(read_image(r, encoding="linear")[0, 0, 0, 0]) == pytest.approx(128 / 255)
    # ... and says so with a gAMA of 1 (PNG 3rd ed., 11.3.3.2), which Pillow reports and the default read honours:
    # without it the linear file read back as sRGB, 0.216 for 0.5
    assert Image.open(r).info.get("gamma") == pytest.approx(1.0)
    assert float(read_image(r)[0, 0, 0, 0]) == pytest.approx(128 / 255)
    assert "gamma" not in Image.open(q).info  # an sRGB file: no gAMA (the sRGB curve is every reader's default)


def test_png_16bit_rgb_round_trip(tmp_path):
    lin = _ramp()
    (p,) = write_image(tmp_path / "a16.png", lin, bits=16)
    codes = np.round(colour.cctf_encoding(lin.permute(1, 2, 0).numpy(), function="sRGB") * 65535)
    # Pillow reads 16-bit RGB PNGs as 8-bit: its value is the high byte of the stored code
    assert np.array_equal(np.asarray(Image.open(p).convert("RGB")), (codes // 256).astype(np.uint8))
    back = read_image(p, dtype=torch.float64)
    np.testing.assert_allclose(back[0].numpy(), colour.cctf_decoding(codes / 65535, function="sRGB")
                               .transpose(2, 0, 1), atol=1e-12)
    assert (back[0] - lin).abs().max() < 1e-4  # 16 bits keep the linear values to 1e-4
    gray = _ramp(c=1)
    (g,) = write_image(tmp_path / "g16.png", gray, bits=16, encoding="linear")
    assert np.array_equal(np.asarray(Image.open(g)), np.round(gray[0].numpy() * 65535).astype(np.uint16))
    assert read_image(g, encoding="linear").shape == (1, 1, 5, 7)


@pytest.mark.parametrize("bits", [8, 16, 32])
def test_tiff(tmp_path, bits):
    lin = _ramp()
    (p,) = write_image(tmp_path / "a.tif", lin, bits=bits)
    stored = tifffile.imread(p)
    if bits == 32:  # float TIFF: linear, unchanged
        assert stored.dtype == np.float32
        np.testing.assert_array_equal(stored, lin.permute(1, 2, 0).numpy().astype(np.float32))
    else:
        full = 2**bits - 1
        expect = np.round(colour.cctf_encoding(lin.permute(1, 2, 0).numpy(), function="sRGB") * full)
        assert np.array_equal(stored, expect.astype(stored.dtype))
    assert (read_image(p, dtype=torch.float64)[0] - lin).abs().max() < {8: 2e-2, 16: 1e-4, 32: 1e-7}[bits]


def test_exr_is_linear_float(tmp_path):
    hdr = _ramp() * 40.0  # scene-referred values beyond 1 are kept
    (p,) = write_image(tmp_path / "a.exr", hdr)
    f = OpenEXR.File(str(p)).channels()
    stored = f["RGB"].pixels if "RGB" in f else np.stack([f[n].pixels for n in "RGB"], -1)
    np.testing.assert_array_equal(stored, hdr.permute(1, 2, 0).numpy().astype(np.float32))
    np.testing.assert_array_equal(read_image(p)[0].numpy(), hdr.float().numpy())


def test_batches_and_errors(tmp_path):
    batch = _ramp(c=3).expand(3, -1, -1, -1) * torch.tensor([0.2, 0.5, 1.0], dtype=torch.float64)[:, None, None, None]
    with pytest.raises(ValueError, match=r"batch of 3.*\{i"):
        write_image(tmp_path / "b.exr", batch)
    paths = write_image(tmp_path / "b_{i}.exr", batch)
    assert [p.name for p in paths] == ["b_0.exr", "b_1.exr", "b_2.exr"]
    for k, p in enumerate(paths):
        torch.testing.assert_close(read_image(p, dtype=torch.float64), batch[k:k + 1], rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError, match=r"values span \[0, 2\].*clip=True"):
        write_image(tmp_path / "c.png", torch.tensor([[[0.0, 2.0]]]).expand(3, 1, 2))
    (c,) = write_image(tmp_path / "c.png", torch.tensor([[[0.0, 2.0]]]).expand(3, 1, 2), clip=True)
    assert np.asarray(Image.open(c))[0, 1, 0] == 255
    with pytest.raises(ValueError, match="bits"):
        write_image(tmp_path / "d.png", _ramp(), bits=32)
    with pytest.raises(ValueError, match="path: expected a file ending"):
        write_image(tmp_path / "d.jpg", _ramp())
    with pytest.raises(ValueError, match="finite"):
        write_image(tmp_path / "e.exr", torch.full((3, 2, 2), float("nan")))
    with pytest.raises(ValueError, match="encoding"):
        read_image(paths[0], encoding="gamma22")
    with pytest.raises(FileNotFoundError, match="no such file"):
        read_image(tmp_path / "missing.png")
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="not a readable PNG"):
        read_image(tmp_path / "bad.png")


def test_read_rgb8_keeps_code_values_and_converts_only_losslessly(tmp_path):
    # read_rgb8 (the benchmark and photo-lifting folders): an 8-bit RGB file's code values unchanged, gray and palette
    # images expanded exactly (Pillow's own conversion is the reference), an opaque alpha dropped; a JPEG is what
    # Pillow decodes (lossy in the file, not in the reading)
    from isettorch.io.images import read_rgb8

    rng = np.random.default_rng(4)
    rgb = rng.integers(0, 256, (9, 7, 3), dtype=np.uint8)
    Image.fromarray(rgb).save(tmp_path / "rgb.png")
    np.testing.assert_array_equal(read_rgb8(tmp_path / "rgb.png"), rgb)
    tifffile.imwrite(tmp_path / "rgb.tif", rgb)
    np.testing.assert_array_equal(read_rgb8(tmp_path / "rgb.tif"), rgb)
    gray = rgb[..., 1]
    Image.fromarray(gray).save(tmp_path / "gray.png")
    np.testing.assert_array_equal(read_rgb8(tmp_path / "gray.png"), np.repeat(gray[..., None], 3, axis=-1))
    pal = Image.fromarray(rgb).quantize(16)
    pal.save(tmp_path / "pal.png")
    np.testing.assert_array_equal(read_rgb8(tmp_path / "pal.png"), np.asarray(pal.convert("RGB")))
    Image.fromarray(np.dstack([rgb, np.full(rgb.shape[:2], 255, np.uint8)])).save(tmp_path / "opaque.png")
    np.testing.assert_array_equal(read_rgb8(tmp_path / "opaque.png"), rgb)
    Image.fromarray(rgb).save(tmp_path / "photo.jpg", quality=90)
    with Image.open(tmp_path / "photo.jpg") as im:
        np.testing.assert_array_equal(read_rgb8(tmp_path / "photo.jpg"), np.asarray(im))


def test_read_rgb8_refuses_what_it_cannot_read_exactly(tmp_path):
    import png

    from isettorch.io.images import read_rgb8

    rng = np.random.default_rng(5)
    rgb = rng.integers(0, 256, (6, 5, 3), dtype=np.uint8)
    alpha = np.full(rgb.shape[:2], 255, np.uint8)
    alpha[2, 3] = 0
    Image.fromarray(np.dstack([rgb, alpha])).save(tmp_path / "transparent.png")
    with pytest.raises(ValueError, match=r"transparent\.png: expected an opaque image, 1 pixels are transparent"):
        read_rgb8(tmp_path / "transparent.png")
    deep = rng.integers(0, 65536, (6, 5 * 3), dtype=np.uint16)  # Pillow reads this as 8-bit RGB, dropping bits
    png.from_array(deep, "RGB;16").save(tmp_path / "deep.png")
    with pytest.raises(ValueError, match=r"deep\.png: expected 8-bit samples"):
        read_rgb8(tmp_path / "deep.png")
    Image.fromarray(deep[:, :5]).save(tmp_path / "gray16.png")
    with pytest.raises(ValueError, match=r"gray16\.png: expected 8-bit samples"):
        read_rgb8(tmp_path / "gray16.png")
    for maxval in (1023, 65535):  # a 10 / 16-bit PPM: Pillow kept 8 of its bits (code maxval / 2 read as 127)
        (tmp_path / "deep.ppm").write_bytes(f"P6\n2 1\n{maxval}\n".encode()
                                            + np.array([0, 1, 2, maxval // 2, maxval, 3], ">u2").tobytes())
        with pytest.raises(ValueError, match=rf"deep\.ppm: expected 8-bit samples, got a RGB/maxval {maxval} image"):
            read_rgb8(tmp_path / "deep.ppm")
    Image.fromarray(rgb).convert("CMYK").save(tmp_path / "cmyk.jpg")
    with pytest.raises(ValueError, match=r"cmyk\.jpg: .*mode 'CMYK'"):
        read_rgb8(tmp_path / "cmyk.jpg")
    (tmp_path / "not.png").write_bytes(b"not an image")
    with pytest.raises(ValueError, match=r"cannot read not\.png as an image"):
        read_rgb8(tmp_path / "not.png")


def test_read_rgb8_shows_a_photograph_in_its_exif_orientation(tmp_path):
    # EXIF orientation 6 (TIFF/EXIF 2.3 tag 0x0112): the stored rows are the displayed image turned 90 degrees
    # counter-clockwise, so it is displayed turned 90 degrees clockwise. Stored: red left half, blue right half
    # (flat halves: JPEG keeps them within a few code values), 16 high and 24 wide; displayed: 24 high and 16 wide
    # with the red half on top.
    from isettorch.io.images import read_rgb8

    stored = np.zeros((16, 24, 3), np.uint8)
    stored[:, :12] = (200, 0, 0)
    stored[:, 12:] = (0, 0, 200)
    im = Image.fromarray(stored)
    exif = im.getexif()
    exif[0x0112] = 6
    im.save(tmp_path / "turned.jpg", exif=exif, quality=95)
    shown = read_rgb8(tmp_path / "turned.jpg")
    assert shown.shape == (24, 16, 3)
    red, blue = np.array([200, 0, 0]), np.array([0, 0, 200])
    assert np.abs(shown[2:10].astype(int) - red).max() <= 8  # rows away from the JPEG ringing at the edge
    assert np.abs(shown[14:22].astype(int) - blue).max() <= 8
    with Image.open(tmp_path / "turned.jpg") as raw:  # the decoded rows as stored, turned clockwise
        np.testing.assert_array_equal(shown, np.rot90(np.asarray(raw), k=-1))


def test_read_rgb8_refuses_a_colour_key_and_several_pages(tmp_path):
    from isettorch.io.images import read_rgb8

    rgb = np.full((6, 5, 3), 100, np.uint8)
    rgb[1, 1] = rgb[4, 2] = (7, 8, 9)
    Image.fromarray(rgb).save(tmp_path / "keyed.png", transparency=(7, 8, 9))  # PNG tRNS: those 2 pixels are clear
    with pytest.raises(ValueError, match=r"keyed\.png: expected an opaque image, 2 pixels are transparent"):
        read_rgb8(tmp_path / "keyed.png")
    gray = np.full((6, 5), 50, np.uint8)
    gray[0, :3] = 0
    Image.fromarray(gray).save(tmp_path / "gray_keyed.png", transparency=0)
    with pytest.raises(ValueError, match=r"gray_keyed\.png: expected an opaque image, 3 pixels are transparent"):
        read_rgb8(tmp_path / "gray_keyed.png")
    import tifffile

    tifffile.imwrite(tmp_path / "float.tif", rgb.astype(np.float32) / 255)  # Pillow: 'cannot identify image file'
    with pytest.raises(ValueError, match=r"float\.tif: expected unsigned 8-bit samples, got float32 samples"):
        read_rgb8(tmp_path / "float.tif")
    Image.fromarray(rgb).save(tmp_path / "unused_key.png", transparency=(1, 2, 3))  # no pixel has the key: opaque
    np.testing.assert_array_equal(read_rgb8(tmp_path / "unused_key.png"), rgb)
    # a palette whose transparent entry no pixel uses is opaque (it was refused); one whose pixels use it is not
    pal = Image.fromarray(rgb).quantize(colors=16)
    used = set(np.unique(np.asarray(pal)).tolist())
    unused = next(i for i in range(256) if i not in used)
    pal.save(tmp_path / "pal_unused.png", transparency=unused)
    np.testing.assert_array_equal(read_rgb8(tmp_path / "pal_unused.png"), np.asarray(pal.convert("RGB")))
    pal.save(tmp_path / "pal_used.png", transparency=int(np.asarray(pal)[0, 0]))
    n_clear = int((np.asarray(pal) == np.asarray(pal)[0, 0]).sum())
    with pytest.raises(ValueError, match=rf"pal_used\.png: expected an opaque image, {n_clear} pixels are transparent "
                                         r"\(the palette's transparent entries"):
        read_rgb8(tmp_path / "pal_used.png")
    page = Image.fromarray(rgb)
    page.save(tmp_path / "pages.tif", save_all=True, append_images=[Image.fromarray(255 - rgb)])
    with pytest.raises(ValueError, match=r"pages\.tif: expected a single image, got 2 pages or frames"):
        read_rgb8(tmp_path / "pages.tif")


def test_photo_folders_leave_out_hidden_files_and_refuse_decompression_bombs(tmp_path, monkeypatch):
    """A copied folder's ``._name.png`` (macOS AppleDouble metadata) is not a photograph: left out by the folder
    readers (evaluate_demosaic, the photo lifter); a photograph over Pillow's decompression-bomb limit is one clear
    ValueError naming the file (Pillow raises an error that is not an OSError)."""
    from PIL import Image as PILImage

    from isettorch.io.images import photo_files, read_rgb8
    from isettorch.isp.evaluation import load_images

    a = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3)
    Image.fromarray(a).save(tmp_path / "b.PNG")
    Image.fromarray(a).save(tmp_path / "a.jpg", quality=95)
    (tmp_path / "._b.PNG").write_bytes(b"\x00\x05\x16\x07 AppleDouble metadata")
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "sub.png").mkdir()  # a folder named like an image is not one (it aborted design-eval)
    Image.fromarray(a).save(tmp_path / "sub.png" / "c.png")  # subfolders are not searched
    assert [p.name for p in photo_files(tmp_path)] == ["a.jpg", "b.PNG"]
    names = [n for n, _ in load_images(tmp_path)]
    assert names == ["a.jpg", "b.PNG"]
    monkeypatch.setattr(PILImage, "MAX_IMAGE_PIXELS", 5)  # 4 x 6 = 24 px is over twice the limit
    with pytest.raises(ValueError, match=r"cannot read b\.PNG: .*reduce the photograph first"):
        read_rgb8(tmp_path / "b.PNG")


@pytest.mark.parametrize("name, bits, value, dtype", [("h.exr", 16, 1e5, "float16"), ("f.exr", 32, 1e39, "float32"),
                                                      ("f.tif", 32, 1e39, "float32")])
def test_float_files_refuse_values_their_type_cannot_hold(tmp_path, name, bits, value, dtype):
    """Finiteness was checked before the narrowing cast, so 1e5 in a half EXR was written as inf and the reader then
    refused the file; now the writer refuses, naming the image. Half's largest value, 65504, is kept exactly."""
    with pytest.raises(ValueError, match=f"image: values up to .* overflow {dtype}"):
        write_image(tmp_path / name, torch.full((3, 2, 2), value, dtype=torch.float64), bits=bits)
    assert not (tmp_path / name).exists()
    (p,) = write_image(tmp_path / "max.exr", torch.full((3, 2, 2), 65504.0), bits=16)
    assert read_image(p).unique().tolist() == [65504.0]


def test_a_batch_with_one_unwritable_sample_writes_no_file(tmp_path):
    """The narrowing cast is checked for the whole batch before the first file: sample 2 at 1e5 in half EXR left
    samples 0 and 1 on disk."""
    x = torch.full((3, 3, 2, 2), 0.5)
    x[2] = 1e5
    with pytest.raises(ValueError, match="image: values up to .* overflow float16"):
        write_image(tmp_path / "im_{i}.exr", x, bits=16)
    assert not list(tmp_path.iterdir())


def test_read_image_puts_a_planar_tiffs_samples_last_and_refuses_pages(tmp_path):
    """A planar RGB TIFF came back channels first and two grey pages as one RGB image (when 4 pixels wide or
    less, silently); an empty PNG raised a bare EOFError."""
    import tifffile

    rgb = (np.random.default_rng(0).random((5, 4, 3)) * 65535).astype(np.uint16)
    tifffile.imwrite(tmp_path / "planar.tif", np.moveaxis(rgb, -1, 0), planarconfig="separate", photometric="rgb")
    got = read_image(tmp_path / "planar.tif", encoding="linear")
    assert got.shape == (1, 3, 5, 4)
    want = (torch.from_numpy(rgb.astype(np.float64)) / 65535).to(got.dtype)
    torch.testing.assert_close(got[0].permute(1, 2, 0), want, rtol=0, atol=0)
    tifffile.imwrite(tmp_path / "pages.tif", np.zeros((2, 5, 3), np.uint8), photometric="minisblack")
    with pytest.raises(ValueError, match="expected one image .* axes 'QYX'"):
        read_image(tmp_path / "pages.tif")
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(ValueError, match="empty.png' is not a readable PNG image"):
        read_image(tmp_path / "empty.png")


def test_photo_folders_read_bmp_webp_gif_and_refuse_formats_they_cannot_read(tmp_path):
    """A folder of photographs in Pillow's 8-bit formats is read whole (a BMP beside a PNG was left out of the mean
    unsaid); a HEIC, AVIF, raw or EXR file in it is refused by name rather than skipped."""
    from PIL import Image

    from isettorch.io.images import photo_files, read_rgb8

    rng = np.random.default_rng(0)
    arrays = {}
    for name in ("a.bmp", "b.png", "c.webp", "d.GIF"):
        a = rng.integers(0, 255, (12, 16, 3), dtype=np.uint8)
        if name.endswith("GIF"):
            a[:] = a[0, 0]  # one colour: a palette holds it exactly
        kw = {"lossless": True} if name.endswith("webp") else {}
        Image.fromarray(a).save(tmp_path / name, **kw)
        arrays[name] = a
    (tmp_path / "notes.txt").write_text("not a photograph")
    files = photo_files(tmp_path)
    assert [f.name for f in files] == ["a.bmp", "b.png", "c.webp", "d.GIF"]
    for f in files:
        np.testing.assert_array_equal(read_rgb8(f), arrays[f.name])
    (tmp_path / "e.HEIC").write_bytes(b"\0")
    with pytest.raises(ValueError, match=r"folder: .* holds image\(s\) in a format not read here: \['e.HEIC'\]"):
        photo_files(tmp_path)


def test_photo_scene_dataset_checks_size_and_length(tmp_path):
    from PIL import Image

    from isettorch.data.photos import PhotoSceneDataset

    Image.fromarray(np.zeros((40, 40, 3), np.uint8)).save(tmp_path / "a.png")
    for kw, name in (({"size": 0}, "size"), ({"size": 2.7}, "size"), ({"length": -3}, "length"),
                     ({"seed": 1.5}, "seed")):
        with pytest.raises(ValueError, match=rf"^{name}: expected"):
            PhotoSceneDataset(tmp_path, **kw)


def test_alpha_is_linear_coverage_in_integer_files(tmp_path):
    """The alpha channel went through the sRGB curve both ways (a linear 0.5 was stored as code 188 and code 128 read
    back as 0.216; an audit against Pillow): alpha is coverage, stored as is (PNG 1.2 section 12.2)."""
    img = torch.full((4, 2, 3), 0.5, dtype=torch.float64)
    write_image(tmp_path / "a.png", img)
    codes = np.asarray(Image.open(tmp_path / "a.png"))
    assert codes.shape == (2, 3, 4)
    assert (codes[..., :3] == 188).all() and (codes[..., 3] == 128).all()  # sRGB(0.5) = 0.7354 -> 188; alpha 128
    back = read_image(tmp_path / "a.png", dtype=torch.float64)
    torch.testing.assert_close(back[0, 3], torch.full((2, 3), 128 / 255, dtype=torch.float64))
    torch.testing.assert_close(back[0, :3], torch.full((3, 2, 3), 0.5, dtype=torch.float64), atol=4e-3, rtol=0)
    Image.fromarray(np.full((2, 3, 2), 128, dtype=np.uint8), mode="LA").save(tmp_path / "la.png")
    la = read_image(tmp_path / "la.png", dtype=torch.float64)
    assert float(la[0, 1, 0, 0]) == pytest.approx(128 / 255) and float(la[0, 0, 0, 0]) < 0.22  # grey decoded


def _profile_with_colorants(colorants) -> bytes:
    """littleCMS's sRGB profile with its rXYZ, gXYZ and bXYZ tags set to ``colorants`` (D50 XYZ, s15Fixed16: ICC.1
    section 10.31), e.g. Display P3's."""
    import struct

    from PIL import ImageCms

    data = bytearray(ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes())
    (count,) = struct.unpack(">I", data[128:132])
    for k in range(count):
        sig, off, _ = struct.unpack(">4sII", data[132 + 12 * k:144 + 12 * k])
        if sig in (b"rXYZ", b"gXYZ", b"bXYZ"):
            xyz = colorants["rgb".index(sig[:1].decode())]
            data[off + 8:off + 20] = struct.pack(">3i", *(round(v * 65536) for v in xyz))
    return bytes(data)


def test_non_srgb_profile_names_display_p3_and_passes_srgb(tmp_path, capsys):
    from PIL import Image, ImageCms

    from isettorch.commands.design_eval import _note_profiles
    from isettorch.io.images import non_srgb_profile

    img = Image.fromarray(np.full((8, 8, 3), 100, np.uint8))
    srgb = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    # Display P3's colorants, Bradford-adapted to D50 (Apple's Display P3 profile)
    p3 = _profile_with_colorants([(0.5151, 0.2412, -0.0011), (0.2919, 0.6922, 0.0419), (0.1571, 0.0666, 0.7841)])
    img.save(tmp_path / "plain.png")
    img.save(tmp_path / "srgb.png", icc_profile=srgb)
    img.save(tmp_path / "p3.png", icc_profile=p3)
    img.save(tmp_path / "p3.jpg", icc_profile=p3)
    assert non_srgb_profile(tmp_path / "plain.png") is None and non_srgb_profile(tmp_path / "srgb.png") is None
    assert non_srgb_profile(tmp_path / "p3.png") == non_srgb_profile(tmp_path / "p3.jpg") == "sRGB built-in"
    _note_profiles(tmp_path)
    err = capsys.readouterr().err
    assert "2 photograph(s) carry colour tags (an ICC profile, a PNG's gAMA or cHRM) that are not sRGB's: p3.jpg" \
        in err and "srgb.png" not in err
    # training on them says so too (design-eval's note alone did): the photo dataset warns at construction
    from isettorch.data.photos import PhotoSceneDataset

    with pytest.warns(UserWarning, match=r"folder: 2 photograph\(s\) carry colour tags .*p3.jpg"):
        PhotoSceneDataset(tmp_path, size=4)
    (tmp_path / "p3.png").unlink()
    (tmp_path / "p3.jpg").unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        PhotoSceneDataset(tmp_path, size=4)


def test_non_srgb_profile_names_a_pngs_gama_and_chrm(tmp_path):
    """design-eval lifts every photograph's codes as sRGB; a PNG tagged gAMA 1.0 (linear samples) or with other
    primaries (cHRM) was lifted so without a note, where read_image decodes the one as linear and refuses the
    other."""
    import struct

    from isettorch.io.images import non_srgb_profile

    codes = np.full((8, 8, 3), 128, np.uint8)
    _png_with_chunks(tmp_path / "linear.png", codes, [(b"gAMA", struct.pack(">I", 100000))])
    _png_with_chunks(tmp_path / "srgb_gamma.png", codes, [(b"gAMA", struct.pack(">I", 45455))])
    _png_with_chunks(tmp_path / "wide.png", codes,
                     [(b"cHRM", struct.pack(">8I", 31270, 32900, 68000, 32000, 26500, 69000, 15000, 6000))])
    assert non_srgb_profile(tmp_path / "linear.png") == "PNG gAMA 1 (code values decode as code^1, not sRGB)"
    assert non_srgb_profile(tmp_path / "srgb_gamma.png") is None
    assert non_srgb_profile(tmp_path / "wide.png") == "PNG cHRM chromaticities other than sRGB's"


def test_design_eval_names_an_oversized_photograph_as_before(tmp_path, monkeypatch, capsys):
    """The ICC note runs before the renders; a photograph over twice Pillow's pixel limit raised its
    DecompressionBombError (neither OSError nor ValueError) out of the note: the command's one line again."""
    from PIL import Image

    from isettorch.cli import main

    Image.fromarray(np.full((40, 40, 3), 100, np.uint8)).save(tmp_path / "big.png")
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 500)  # 1600 px: over twice the limit
    assert main(["design-eval", "bayer_rgb", str(tmp_path), "--quiet"]) == 2
    assert "DIR: cannot read big.png" in capsys.readouterr().err


def test_png_with_an_sbit_chunk_reads_its_stored_samples(tmp_path):
    # pypng writes a 12-bit grey file as 16-bit samples scaled to the full range plus an sBIT chunk of 12; the
    # stored samples (Pillow's reading) are the image, sBIT only records the source's precision (PNG 1.2, 4.2.6.4).
    import png

    codes = np.array([[0, 1, 2048, 4095]], np.uint16)
    with open(tmp_path / "s12.png", "wb") as fh:
        png.Writer(width=4, height=1, greyscale=True, bitdepth=12).write(fh, codes.tolist())
    stored = np.asarray(Image.open(tmp_path / "s12.png")).astype(np.float64) / 65535
    got = read_image(tmp_path / "s12.png", encoding="linear", dtype=torch.float64)
    np.testing.assert_allclose(got[0, 0].numpy(), stored, rtol=0, atol=1e-12)
    assert got[0, 0, 0, -1] == 1.0  # white stays white (it read 0.055: the 12-bit codes times 255 overflowed uint16)


def test_tiff_colour_models_other_than_grey_and_rgb_are_refused_by_name(tmp_path):
    tifffile.imwrite(tmp_path / "mw.tif", np.array([[0, 255]], np.uint8), photometric="miniswhite")
    tifffile.imwrite(tmp_path / "cmyk.tif", np.array([[[0, 255, 255, 0]]], np.uint8), photometric="separated")
    pal = Image.new("P", (3, 1))
    pal.putpalette([255, 0, 0, 0, 255, 0, 0, 0, 255] + [0] * 759)
    pal.putdata([0, 1, 2])
    pal.save(tmp_path / "pal.tif")  # read as its indices 0, 1, 2 (grey), min-is-white inverted, CMYK as RGBA
    for name, model in (("mw", "MINISWHITE"), ("cmyk", "SEPARATED"), ("pal", "PALETTE")):
        with pytest.raises(ValueError, match=rf"{name}\.tif.*interpretation MINISBLACK or RGB, got {model}"):
            read_image(tmp_path / f"{name}.tif")


@pytest.mark.parametrize("orientation", range(1, 9))
def test_read_image_applies_the_orientation_tag_as_pillow_does(tmp_path, orientation):
    from PIL import ImageOps

    from isettorch.io.images import read_rgb8

    stored = (np.random.default_rng(orientation).random((4, 6, 3)) * 255).astype(np.uint8)
    im = Image.fromarray(stored)
    exif = im.getexif()
    exif[0x0112] = orientation
    im.save(tmp_path / "o.png", exif=exif.tobytes())
    tifffile.imwrite(tmp_path / "o.tif", stored, photometric="rgb", extratags=[(274, "H", 1, orientation, False)])
    for name in ("o.png", "o.tif"):
        with Image.open(tmp_path / name) as raw:
            shown = np.asarray(ImageOps.exif_transpose(raw))
        got = read_image(tmp_path / name, encoding="linear", dtype=torch.float64)[0].permute(1, 2, 0).numpy()
        np.testing.assert_array_equal(np.round(got * 255).astype(np.uint8), shown)
    np.testing.assert_array_equal(read_rgb8(tmp_path / "o.png"), shown)  # the two readers agree


def test_grey_and_alpha_round_trips_in_every_format(tmp_path):
    x = torch.rand(2, 5, 7, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    for name, bits, tol in (("la.png", 16, 0.5 / 65535 * 2.5), ("la.tif", 16, 0.5 / 65535 * 2.5), ("la.exr", 32, 1e-7)):
        write_image(tmp_path / name, x, bits=bits)
        back = read_image(tmp_path / name, dtype=torch.float64)
        assert back.shape == (1, 2, 5, 7)
        torch.testing.assert_close(back[0], x, rtol=0, atol=tol)  # half a code through sRGB's decode (slope <= 2.4)
        np.testing.assert_allclose(back[0, 1].numpy(), np.round(x[1].numpy() * (2**bits - 1)) / (2**bits - 1)
                                   if bits == 16 else x[1].numpy(), atol=1e-7)  # alpha: linear coverage
    import png

    info = png.Reader(filename=str(tmp_path / "la.png")).read()[3]
    assert info["greyscale"] and info["alpha"] and info["bitdepth"] == 16
    assert tifffile.TiffFile(tmp_path / "la.tif").pages[0].extrasamples == (2,)  # unassociated alpha
    channels = {"Y": np.full((2, 2), 0.5, np.float32), "A": np.full((2, 2), 0.25, np.float32)}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, channels).write(str(tmp_path / "ya.exr"))
    ya = read_image(tmp_path / "ya.exr")  # its alpha was dropped: one channel; grey premultiplied (OpenEXR)
    assert ya.shape == (1, 2, 2, 2) and ya[0, 0].eq(2.0).all() and ya[0, 1].eq(0.25).all()


def test_a_tiff_without_a_photometric_tag_reads_its_samples(tmp_path):
    """The tag is required by TIFF 6.0 but some writers omit it: tifffile gives 0 (no name), which crashed the
    photometric check with an AttributeError; such files read as their samples, as before."""
    import struct

    grey = (np.arange(24, dtype=np.uint16).reshape(4, 6) * 1000)
    tifffile.imwrite(tmp_path / "nophot.tif", grey, photometric="minisblack")
    data = bytearray((tmp_path / "nophot.tif").read_bytes())
    with tifffile.TiffFile(tmp_path / "nophot.tif") as tif:
        offset = tif.pages[0].tags["PhotometricInterpretation"].offset
    struct.pack_into("<H", data, offset, 65000)  # the tag's code renamed to an unknown one: no photometric tag
    (tmp_path / "nophot.tif").write_bytes(bytes(data))
    with tifffile.TiffFile(tmp_path / "nophot.tif") as tif:
        assert tif.pages[0].tags.get("PhotometricInterpretation") is None
    got = read_image(tmp_path / "nophot.tif", encoding="linear", dtype=torch.float64)
    np.testing.assert_array_equal(got[0, 0].numpy(), grey / 65535)


def test_photo_folders_read_jfif_jpe_pbm_dib_qoi_and_name_jpeg2000(tmp_path, recwarn):
    """photo audit (2026-12-01): a .jfif (how browsers save JPEGs), .jpe, .pbm, .dib or .qoi photograph beside a
    PNG was left out of the mean unsaid; a JPEG 2000 .jpf is refused by name; Pillow's size warning, named no file,
    printed amid the output (its filter was set after the file was opened)."""
    from PIL import Image as PILImage

    from isettorch.io.images import photo_files, read_rgb8

    a = np.random.default_rng(1).integers(0, 255, (8, 10, 3), dtype=np.uint8)
    Image.fromarray(a).save(tmp_path / "a.png")
    for name, fmt in (("b.jfif", "JPEG"), ("c.jpe", "JPEG"), ("d.dib", "DIB"), ("e.qoi", "QOI")):
        Image.fromarray(a).save(tmp_path / name, format=fmt, **({"quality": 95} if fmt == "JPEG" else {}))
    Image.fromarray(a[..., 0] > 127).save(tmp_path / "f.pbm")
    assert [p.name for p in photo_files(tmp_path)] == ["a.png", "b.jfif", "c.jpe", "d.dib", "e.qoi", "f.pbm"]
    np.testing.assert_array_equal(read_rgb8(tmp_path / "e.qoi"), a)  # lossless
    (tmp_path / "g.jpf").write_bytes(b"\0")
    with pytest.raises(ValueError, match=r"format not read here: \['g.jpf'\]"):
        photo_files(tmp_path)
    old = PILImage.MAX_IMAGE_PIXELS
    try:
        PILImage.MAX_IMAGE_PIXELS = 60  # 80 px: over the limit (a warning), under twice it (no error)
        read_rgb8(tmp_path / "a.png")
    finally:
        PILImage.MAX_IMAGE_PIXELS = old
    assert not [w for w in recwarn if issubclass(w.category, PILImage.DecompressionBombWarning)]


def _png_with_chunks(path, codes, chunks):
    """An 8-bit RGB PNG of ``codes`` [H, W, 3] carrying the given ancillary chunks (Pillow's PngInfo)."""
    from PIL import PngImagePlugin

    info = PngImagePlugin.PngInfo()
    for kind, data in chunks:
        info.add(kind, data)
    Image.fromarray(codes).save(path, pnginfo=info)
    return path


def test_png_colour_chunks_decide_the_decoding(tmp_path):
    """read_image decoded every integer PNG with the sRGB curve, whatever it said of itself (PNG 3rd ed. 11.3.3):
    a gAMA of 1.0 (linear samples: code 128 is 0.502 of white, not 0.216) now reads as linear, another gamma as
    code ^ (1 / gamma); an sRGB chunk takes precedence over gAMA; colours other than sRGB's (cHRM primaries, a
    non-sRGB ICC profile) raise naming the file. encoding='linear' returns the code values whatever the tags."""
    import struct

    from PIL import ImageCms

    codes = np.full((2, 3, 3), 128, np.uint8)
    gama = lambda g: (b"gAMA", struct.pack(">I", round(g * 1e5)))  # noqa: E731
    srgb_128 = colour.cctf_decoding(128 / 255, function="sRGB")
    cases = {"linear": ([gama(1.0)], 128 / 255), "srgb_gamma": ([gama(0.45455)], srgb_128),
             "mac": ([gama(0.55556)], (128 / 255) ** (1 / 0.55556)),
             "srgb_chunk": ([(b"sRGB", b"\0"), gama(1.0)], srgb_128),
             "srgb_chrm": ([(b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000))],
                           srgb_128)}
    for name, (chunks, want) in cases.items():
        got = read_image(_png_with_chunks(tmp_path / f"{name}.png", codes, chunks), dtype=torch.float64)
        torch.testing.assert_close(got, torch.full((1, 3, 2, 3), want, dtype=torch.float64), rtol=1e-12, atol=0,
                                   msg=name)
    wide = _png_with_chunks(tmp_path / "wide.png", codes,
                            [(b"cHRM", struct.pack(">8I", 31270, 32900, 68000, 32000, 26500, 69000, 15000, 6000))])
    with pytest.raises(ValueError, match=r"path: .*wide\.png' has cHRM chromaticities .*not sRGB's"):
        read_image(wide)
    lab = tmp_path / "lab.png"
    Image.fromarray(codes).save(lab, icc_profile=ImageCms.ImageCmsProfile(ImageCms.createProfile("LAB")).tobytes())
    with pytest.raises(ValueError, match=r"path: .*lab\.png' carries the ICC profile .*not sRGB"):
        read_image(lab)
    srgb_icc = tmp_path / "srgb_icc.png"
    Image.fromarray(codes).save(srgb_icc,
                                icc_profile=ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes())
    assert read_image(srgb_icc, dtype=torch.float64).unique().item() == pytest.approx(srgb_128, rel=1e-12)
    for p in (wide, lab, tmp_path / "mac.png"):
        assert read_image(p, encoding="linear", dtype=torch.float64).unique().item() == 128 / 255


def test_float64_tiff_keeps_its_range_and_exr_mixes_half_and_float(tmp_path):
    """A float64 TIFF was narrowed to float32 on reading: 1e39 became inf and the file was refused as non-finite;
    it now reads as float64 (and a float32 result beyond float32's range raises naming dtype). An EXR whose
    channels mix half and float was refused ("cannot coalesce"); a UINT channel reads exactly above 2^24."""
    a = np.array([[[1e39, 0.1, 1.0 + 2**-40]]])
    tifffile.imwrite(tmp_path / "d.tif", a, photometric="rgb")
    got = read_image(tmp_path / "d.tif", dtype=torch.float64)
    assert got.dtype == torch.float64 and got.flatten().tolist() == a.flatten().tolist()
    with pytest.raises(ValueError, match="dtype: .*beyond torch.float32's range"):
        read_image(tmp_path / "d.tif")
    chans = {"R": np.full((2, 3), 0.5, np.float16), "G": np.full((2, 3), 0.1, np.float32),
             "B": np.full((2, 3), 3.0, np.float32)}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, chans).write(str(tmp_path / "mix.exr"))
    got = read_image(tmp_path / "mix.exr")
    assert got[0, :, 0, 0].tolist() == [0.5, float(np.float32(0.1)), 3.0]
    big = np.full((2, 3), 2**24 + 1, np.uint32)
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"Y": big}).write(str(tmp_path / "u.exr"))
    assert read_image(tmp_path / "u.exr", dtype=torch.float64).unique().item() == 2**24 + 1


def test_read_image_closes_the_png_it_reads(tmp_path):
    """pypng's Reader(filename=) opened the file and left it to the garbage collector (a ResourceWarning per
    read, and open handles in a loop over a folder)."""
    import gc
    import warnings

    (p,) = write_image(tmp_path / "a.png", torch.full((3, 4, 4), 0.25))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        read_image(p)
        gc.collect()
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)]


def test_a_batch_that_fails_at_a_later_file_leaves_every_file_as_it_was(tmp_path):
    """Files were written one after another: a batch whose third file could not be written (its folder missing)
    left the first two written and an older file of that name overwritten. Now each is written under a temporary
    name and all are moved into place only at the end."""
    (tmp_path / "d0").mkdir()
    (tmp_path / "d1").mkdir()
    old = (tmp_path / "d0" / "img.png")
    old.write_bytes(b"older file")
    with pytest.raises(OSError):
        write_image(tmp_path / "d{i}" / "img.png", torch.full((3, 3, 4, 4), 0.5))
    assert old.read_bytes() == b"older file"
    assert sorted(p.name for p in (tmp_path / "d0").iterdir()) == ["img.png"]
    assert not list((tmp_path / "d1").iterdir())
    write_image(tmp_path / "d{i}" / "img.png", torch.full((2, 3, 4, 4), 0.5))
    assert read_image(old).shape == (1, 3, 4, 4)


def test_read_rgb8_refuses_a_planar_16_bit_tiff_and_a_corrupt_tiff_prints_nothing(tmp_path, capfd):
    """A 16-bit TIFF of one plane per colour (PlanarConfiguration 2) has Pillow tiles 'R', 'G', 'B' whatever the
    depth: the 16-bit check passed and its samples were decoded as bytes (a photograph scored 15 dB for 32). A TIFF
    Pillow cannot open sent tifffile's own error lines to stderr beside the command's one line."""
    from isettorch.io.images import read_rgb8

    img = np.random.default_rng(0).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    planar = tmp_path / "planar16.tif"
    tifffile.imwrite(planar, np.moveaxis(img.astype(np.uint16) * 257, -1, 0), photometric="rgb",
                     planarconfig="separate")
    assert [t[3][0] if isinstance(t[3], tuple) else t[3] for t in Image.open(planar).tile] == ["R", "G", "B"]
    with pytest.raises(ValueError, match=r"planar16.tif: expected 8-bit samples, got uint16 samples \(TIFF\)"):
        read_rgb8(planar)
    for name, kw in (("lzw.tif", {"compression": "tiff_lzw"}), ("plain.tif", {})):  # 8-bit TIFFs still read
        Image.fromarray(img).save(tmp_path / name, **kw)
        assert np.array_equal(read_rgb8(tmp_path / name), img)
    Image.fromarray(img[..., 0] > 128).save(tmp_path / "bilevel.tif")  # (1-bit: bool samples)
    assert read_rgb8(tmp_path / "bilevel.tif").shape == (24, 32, 3)
    data = bytearray((tmp_path / "plain.tif").read_bytes())
    ifd = int.from_bytes(data[4:8], "little")
    for k in range(int.from_bytes(data[ifd:ifd + 2], "little")):  # StripOffsets given a type that does not exist
        entry = ifd + 2 + 12 * k
        if int.from_bytes(data[entry:entry + 2], "little") == 273:
            data[entry + 2:entry + 4] = (29956).to_bytes(2, "little")
    (tmp_path / "bad.tif").write_bytes(bytes(data))
    capfd.readouterr()
    with pytest.raises(ValueError, match=r"cannot read bad.tif as an image"):
        read_rgb8(tmp_path / "bad.tif")
    assert capfd.readouterr().err == ""


def test_premultiplied_alpha_of_exr_and_associated_tiff_reads_as_straight(tmp_path):
    # OpenEXR stores colour premultiplied by alpha (Technical Introduction); TIFF ExtraSamples 1 is associated alpha
    # (TIFF 6.0). A half-covered red pixel, premultiplied (0.5, 0, 0, 0.5), is straight (1, 0, 0, 0.5), as the PNG
    # of it reads: both read (0.5, 0, 0, 0.5), and write_image stored straight red 1 in an EXR (red 2 to a reader).
    px = np.array([0.5, 0.0, 0.0, 0.5], np.float32)
    chans = {c: np.full((2, 2), v, np.float32) for c, v in zip("RGBA", px)}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, chans).write(str(tmp_path / "p.exr"))
    tifffile.imwrite(tmp_path / "p.tif", np.tile(px, (2, 2, 1)), photometric="rgb", extrasamples=["assocalpha"])
    transparent = {**chans, "A": np.zeros((2, 2), np.float32)}  # alpha 0: the stored light as it is
    OpenEXR.File({"type": OpenEXR.scanlineimage}, transparent).write(str(tmp_path / "t.exr"))
    for name in ("p.exr", "p.tif"):
        np.testing.assert_array_equal(read_image(tmp_path / name)[0, :, 0, 0].numpy(), [1.0, 0.0, 0.0, 0.5])
    np.testing.assert_array_equal(read_image(tmp_path / "t.exr")[0, :, 0, 0].numpy(), [0.5, 0.0, 0.0, 0.0])
    write_image(tmp_path / "w.exr", torch.tensor([1.0, 0.0, 0.0, 0.5]).reshape(4, 1, 1).expand(4, 2, 2))
    stored = OpenEXR.File(str(tmp_path / "w.exr"), separate_channels=True).channels()
    assert float(stored["R"].pixels[0, 0]) == 0.5 and float(stored["A"].pixels[0, 0]) == 0.5


def test_an_associated_alpha_8_bit_tiff_is_divided_in_code_values_as_pillow_does(tmp_path):
    # TIFF premultiplies the stored values: straight sRGB code 124 (linear 0.2) at alpha 128 is stored as 62. Pillow
    # divides the codes (123 of 255); read_image divided after decoding, reading 0.096 for 0.2.
    stored = np.array([[[62, 62, 62, 128]]], np.uint8)
    tifffile.imwrite(tmp_path / "a.tif", stored, photometric="rgb", extrasamples=["assocalpha"])
    straight = np.asarray(Image.open(tmp_path / "a.tif").convert("RGBA"))[0, 0]
    got = read_image(tmp_path / "a.tif", dtype=torch.float64)[0, :, 0, 0]
    expected = float(colour.cctf_decoding(62 / 128, "sRGB"))  # the codes divided, then decoded
    np.testing.assert_allclose(got[:3].numpy(), expected, rtol=1e-12)
    assert float(got[0]) == pytest.approx(0.2, abs=2e-3)  # linear 0.2, as written
    assert abs(float(got[0]) - float(colour.cctf_decoding(straight[0] / 255, "sRGB"))) < 3e-3  # Pillow's, rounded
    assert float(got[3]) == pytest.approx(128 / 255)


def test_files_in_other_colours_than_srgb_are_refused_unless_read_linear(tmp_path):
    # An ACES2065-1 EXR (AP0 chromaticities) read as linear sRGB (0.2, 0.4, 0.6 for colour-science's
    # (-0.18, 0.44, 0.64)); a TIFF's Display P3 ICC profile ignored (a PNG's is refused); a luminance / chroma EXR
    # (Y, RY, BY) read as grey. encoding='linear' returns a tagged file's stored values.
    from PIL import ImageCms

    ap0 = (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.077, 0.32168, 0.33767)
    rgb = {c: np.full((2, 2), v, np.float32) for c, v in zip("RGB", (0.2, 0.4, 0.6))}
    OpenEXR.File({"type": OpenEXR.scanlineimage, "chromaticities": ap0}, rgb).write(str(tmp_path / "aces.exr"))
    with pytest.raises(ValueError, match="aces.exr.*chromaticities"):
        read_image(tmp_path / "aces.exr")
    np.testing.assert_allclose(read_image(tmp_path / "aces.exr", encoding="linear")[0, :, 0, 0].numpy(),
                               [0.2, 0.4, 0.6], rtol=1e-7)
    srgb = (0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3127, 0.329)
    OpenEXR.File({"type": OpenEXR.scanlineimage, "chromaticities": srgb}, rgb).write(str(tmp_path / "srgb.exr"))
    assert read_image(tmp_path / "srgb.exr").shape == (1, 3, 2, 2)
    lab = ImageCms.ImageCmsProfile(ImageCms.createProfile("LAB")).tobytes()  # a profile that is not sRGB
    tifffile.imwrite(tmp_path / "lab.tif", np.full((2, 2, 3), 200, np.uint8), photometric="rgb",
                     extratags=[(34675, 7, len(lab), lab, True)])
    with pytest.raises(ValueError, match="lab.tif.*ICC profile"):
        read_image(tmp_path / "lab.tif")
    assert read_image(tmp_path / "lab.tif", encoding="linear")[0, 0, 0, 0] == pytest.approx(200 / 255)
    yc = {"Y": np.full((2, 2), 0.5, np.float32), "RY": np.ones((2, 2), np.float32),
          "BY": np.full((2, 2), -0.5, np.float32)}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, yc).write(str(tmp_path / "yc.exr"))
    with pytest.raises(ValueError, match="yc.exr.*luminance / chroma"):
        read_image(tmp_path / "yc.exr")


def test_read_image_names_a_tiff_with_no_image_in_it(tmp_path):
    """A corrupt TIFF (a header and nothing readable) is a ValueError naming the path, as a corrupt PNG is; it was a
    bare IndexError from tifffile's empty series list."""
    (tmp_path / "x.tif").write_bytes(b"II*\x00garbage")
    with pytest.raises(ValueError, match=r"path: .*x\.tif' is not a readable TIFF image \(no image in the file\)"):
        read_image(tmp_path / "x.tif")
