"""Benchmark scoring and the ``demosaic-eval`` command: CPSNR against an independent numpy computation with
colour-demosaicing, on generated images and on crops of the shared benchmark sets (skipped when absent)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import colour_demosaicing as cd
import numpy as np
import pytest
import torch
from PIL import Image
from shared_paths import DATA

from isettorch.cli import main
from isettorch.isp import cpsnr, demosaic, evaluate_demosaic

REPO = Path(__file__).resolve().parents[2]
REFERENCE = {"bilinear_colour": cd.demosaicing_CFA_Bayer_bilinear, "malvar2004": cd.demosaicing_CFA_Bayer_Malvar2004,
             "menon2007": cd.demosaicing_CFA_Bayer_Menon2007}


def _numpy_cpsnr(image_u8, method, pattern="RGGB", crop=0):
    """The benchmark convention, written independently with numpy and colour-demosaicing."""
    truth = image_u8.astype(np.float64) / 255
    out = np.clip(REFERENCE[method](cd.mosaicing_CFA_Bayer(truth, pattern), pattern), 0, 1)
    sl = slice(crop, -crop if crop else None)
    return 10 * np.log10(1 / np.mean((out[sl, sl] - truth[sl, sl]) ** 2)), out


def _smooth_images(n, h, w, seed=0):
    rng = np.random.default_rng(seed)
    ims = []
    for _ in range(n):
        y, x = np.mgrid[0:h, 0:w] / max(h, w)
        f = rng.uniform(2, 8, size=3)
        base = [0.5 + 0.4 * np.sin(f[c] * x + (c + 1) * y * f[(c + 1) % 3]) for c in range(3)]
        ims.append(np.clip(np.stack(base, -1) * 255 + rng.normal(0, 6, (h, w, 3)), 0, 255).round().astype(np.uint8))
    return ims


def test_cpsnr_analytic():
    ref = torch.full((2, 3, 8, 8), 0.5, dtype=torch.float64)
    est = ref + 0.1  # MSE 0.01 -> 20 dB
    est[1, :, 0, :] = 0.5 + 0.4  # a wrong border row in the second image only
    np.testing.assert_allclose(cpsnr(est, ref, crop=1).numpy(), [20.0, 20.0], atol=1e-12)
    mse1 = (0.01 * (64 - 8) + 0.16 * 8) / 64
    np.testing.assert_allclose(cpsnr(est, ref).numpy(), [20.0, 10 * np.log10(1 / mse1)], atol=1e-12)
    with pytest.raises(ValueError, match="crop"):
        cpsnr(est, ref, crop=4)


@pytest.mark.parametrize("method", ["malvar2004", "menon2007"])
@pytest.mark.parametrize("pattern", ["RGGB", "GBRG"])
def test_evaluate_matches_numpy_reference(method, pattern):
    ims = _smooth_images(2, 30, 26, seed=1)
    res = evaluate_demosaic([(f"im{i}", a) for i, a in enumerate(ims)], method, pattern, crop=3, dtype=torch.float64)
    expected = [_numpy_cpsnr(a, method, pattern, crop=3)[0] for a in ims]
    # Menon's direction choice compares two sums; where they tie in exact arithmetic, rounding decides, in a
    # different order in scipy and torch (a few pixels in a thousand): compare scores to 0.05 dB there.
    tol = 0.05 if method == "menon2007" else 1e-9
    np.testing.assert_allclose([r["cpsnr"] for r in res["images"]], expected, rtol=0, atol=tol)
    assert res["mean_cpsnr"] == pytest.approx(np.mean(expected), abs=tol)


def test_cli_json(tmp_path, capsys):
    ims = _smooth_images(3, 24, 20, seed=2)
    names = ["a.png", "b.png", "c.tif"]
    for name, a in zip(names, ims):
        Image.fromarray(a).save(tmp_path / name)
    (tmp_path / "notes.txt").write_text("ignored")
    assert main(["demosaic-eval", str(tmp_path), "--method", "malvar2004", "--pattern", "GRBG", "--crop", "2",
                 "--dtype", "float64", "--json", "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert set(res) == {"method", "network", "pattern", "crop", "mean_cpsnr", "exact_images", "ms_per_image",
                        "images", "noise_sigma", "noise_shot", "seed", "denoise", "dtype", "ms_per_megapixel"}
    assert (res["method"], res["network"], res["pattern"], res["crop"]) == ("malvar2004", None, "GRBG", 2)
    assert [r["name"] for r in res["images"]] == names
    expected = [_numpy_cpsnr(a, "malvar2004", "GRBG", crop=2)[0] for a in ims]
    np.testing.assert_allclose([r["cpsnr"] for r in res["images"]], expected, rtol=0, atol=1e-9)
    assert res["mean_cpsnr"] == pytest.approx(np.mean(expected), abs=1e-9)
    assert res["ms_per_image"] > 0

    assert main(["demosaic-eval", str(tmp_path), "--method", "nearest"]) == 0
    out = capsys.readouterr().out
    assert "mean CPSNR" in out and "c.tif" in out


def test_cli_errors(tmp_path, capsys):
    assert main(["demosaic-eval", str(tmp_path), "--json"]) == 2
    assert re.fullmatch(r"isettorch demosaic-eval: DIR: no \.png.* files in .*\n", capsys.readouterr().err)
    Image.fromarray(np.zeros((8, 8, 4), np.uint8)).save(tmp_path / "clear.png")  # transparent: not a photograph
    assert main(["demosaic-eval", str(tmp_path)]) == 2
    assert re.search(r"DIR: .*clear\.png: expected an opaque image", capsys.readouterr().err)
    (tmp_path / "clear.png").unlink()
    Image.fromarray(np.full((8, 9, 3), 128, np.uint8)).save(tmp_path / "odd.png")
    # every method takes odd sizes (a learned one completes the Bayer cells by reflection); a method's own refusal
    # names the image
    assert main(["demosaic-eval", str(tmp_path), "--method", "malvar2004", "--json", "--crop", "0"]) == 0
    capsys.readouterr()
    assert main(["demosaic-eval", str(tmp_path), "--method", "learned_tiny", "--quiet", "--crop", "0"]) == 0
    assert "odd.png" in capsys.readouterr().out
    (tmp_path / "odd.png").unlink()
    Image.fromarray(np.full((3, 9, 3), 128, np.uint8)).save(tmp_path / "thin.png")
    assert main(["demosaic-eval", str(tmp_path), "--method", "learned_tiny", "--quiet", "--crop", "0"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(r"DIR: thin\.png \(9 x 3 px, W x H\): raw: expected a height and "
                                             r"width of at least 4", err)


def test_an_exactly_reproduced_image_is_counted_not_averaged(tmp_path, capsys):
    """A flat image is demosaiced exactly (MSE 0, CPSNR inf): the mean is over the other images, the exact ones are
    counted beside it, in the table and in valid JSON (cpsnr null, "exact": true)."""
    smooth = _smooth_images(1, 24, 20, seed=3)[0]
    white = np.full((16, 16, 3), 255, np.uint8)
    expected = _numpy_cpsnr(smooth, "malvar2004", crop=2)[0]  # the only finite score
    truth = white.astype(np.float64) / 255  # colour-demosaicing reproduces the flat image exactly: MSE 0
    assert np.array_equal(np.clip(cd.demosaicing_CFA_Bayer_Malvar2004(cd.mosaicing_CFA_Bayer(truth)), 0, 1), truth)
    res = evaluate_demosaic([("b_smooth", smooth), ("w_white", white)], "malvar2004", crop=2, dtype=torch.float64)
    assert res["mean_cpsnr"] == pytest.approx(expected, abs=1e-9)
    assert res["exact_images"] == 1
    assert [(r["name"], r["exact"]) for r in res["images"]] == [("b_smooth", False), ("w_white", True)]
    assert res["images"][1]["cpsnr"] == np.inf
    Image.fromarray(smooth).save(tmp_path / "b_smooth.png")
    Image.fromarray(white).save(tmp_path / "w_white.png")
    args = ["demosaic-eval", str(tmp_path), "--method", "malvar2004", "--crop", "2", "--dtype", "float64", "--quiet"]
    assert main([*args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)  # strict JSON: no Infinity or NaN
    assert out["mean_cpsnr"] == pytest.approx(expected, abs=1e-9) and out["exact_images"] == 1
    assert [(r["cpsnr"], r["exact"]) for r in out["images"]][1] == (None, True)
    assert main(args) == 0
    table = capsys.readouterr().out
    assert f"mean CPSNR {expected:.3f} dB over 1 of 2 images (1 reproduced exactly" in table
    (tmp_path / "b_smooth.png").unlink()  # every image exact: no finite score to average
    assert main([*args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["mean_cpsnr"] is None and out["exact_images"] == 1 and out["images"][0]["exact"] is True


def test_every_image_is_checked_before_the_first_is_scored():
    calls = []

    def method(raw, pattern):
        calls.append(raw.shape)
        return demosaic(raw, pattern, "bilinear")

    big, small = _smooth_images(1, 16, 16)[0], _smooth_images(1, 8, 8)[0]
    with pytest.raises(ValueError, match=r"crop: small is 8 x 8 px, too small for a 5-pixel border \(at most 3"):
        evaluate_demosaic([("big", big), ("small", small)], method, crop=5)
    with pytest.raises(ValueError, match=r"images: strip is 96 x 1 px; expected at least 2 px each way"):
        evaluate_demosaic([("big", big), ("strip", np.zeros((1, 96, 3), np.uint8))], method)
    assert calls == []  # nothing scored before the bad image was found

    def broken(raw, pattern):
        return torch.full((1, 3, *raw.shape[-2:]), float("nan"))

    # (a callable is named by its type) 3 x 16 x 16 NaN
    with pytest.raises(ValueError, match=r"method: function returned 768 NaN/inf values for big"):
        evaluate_demosaic([("big", big)], broken)


def test_check_device():
    from isettorch.isp.evaluation import check_device

    assert check_device("cpu") == torch.device("cpu")
    for name, message in (("fpga", "cannot compute on 'fpga'"), ("foo", "'foo' is not a torch device"),
                          ("meta", "'meta' holds no values")):
        with pytest.raises(ValueError, match=f"device: {message}"):
            check_device(name)


def _benchmark_crops():
    if not DATA.is_dir():
        pytest.skip(f"benchmark images not found at {DATA} (set ISETTORCH_DATA)")
    picks = [("kodak24/01.png", 200, 300), ("kodak24/19.png", 300, 150), ("mcmaster18/1.tif", 100, 100)]
    out = []
    for rel, y, x in picks:
        path = DATA / rel
        if not path.exists():
            pytest.skip(f"benchmark image {path} not found")
        with Image.open(path) as im:
            out.append((rel, np.asarray(im.convert("RGB"))[y:y + 96, x:x + 96]))
    return out


@pytest.mark.parametrize("method", sorted(REFERENCE))
def test_benchmark_crops_agree_with_colour_demosaicing(method):
    for name, a in _benchmark_crops():
        truth = torch.from_numpy(a.astype(np.float64) / 255).permute(2, 0, 1)[None]
        for crop in (0, 10):
            ref_score, ref_out = _numpy_cpsnr(a, method, crop=crop)
            ours = evaluate_demosaic([(name, a)], method, "RGGB", crop, dtype=torch.float64)["mean_cpsnr"]
            assert abs(ours - ref_score) < 0.05, (name, crop, ours, ref_score)
        out = demosaic(torch.from_numpy(cd.mosaicing_CFA_Bayer(a / 255.0, "RGGB"))[None, None], "RGGB", method)
        agree = np.isclose(out[0].permute(1, 2, 0).clamp(0, 1).numpy(), ref_out, rtol=0, atol=1e-9).mean()
        assert agree > (0.99 if method == "menon2007" else 0.999999), (name, agree)  # Menon: rounding-decided ties
        assert truth.shape[-2:] == (96, 96)


@pytest.mark.parametrize("method", ["bilinear", "malvar2004", "menon2007"])
def test_a_flat_mid_grey_is_exact_at_float32(method):
    """At the default float32 a flat mid-grey (code 128: 128/255 is not a float32 number) reproduced to float32
    rounding (bilinear exactly, MHC to 1 ulp) scored 140-150 dB against the float64 truth and lifted a folder's
    mean from 27.6 to 89.1 dB; within 8 ulps of the truth as the method received it, it is exact and the mean is
    the other image's, as at float64 (to 1e-4 dB)."""
    grey = np.full((16, 16, 3), 128, np.uint8)
    smooth = _smooth_images(1, 24, 20, seed=3)[0]
    res32 = evaluate_demosaic([("grey", grey), ("smooth", smooth)], method, crop=2, dtype=torch.float32)
    res64 = evaluate_demosaic([("grey", grey), ("smooth", smooth)], method, crop=2, dtype=torch.float64)
    assert [r["exact"] for r in res32["images"]] == [True, False] and res32["exact_images"] == 1
    assert res32["mean_cpsnr"] == pytest.approx(res64["mean_cpsnr"], abs=1e-4)


def test_the_learned_method_names_the_network_it_ran(tmp_path, capsys):
    """With noise the learned method runs the joint denoise network, without it the noise-free one: the JSON and the
    table say which (both said only "learned")."""
    Image.fromarray(_smooth_images(1, 16, 16, seed=2)[0]).save(tmp_path / "a.png")
    for extra, network in (([], "noise_free"), (["--noise-sigma", "0.02"], "joint_denoise")):
        args = ["demosaic-eval", str(tmp_path), "--method", "learned", "--quiet", *extra]
        assert main([*args, "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["network"] == network
        assert main(args) == 0
        assert f"method learned ({network} network)" in capsys.readouterr().out


def test_the_warm_up_runs_on_a_corner_of_the_first_image():
    """The timed evaluation warms the method up once, on the first image's top-left 64 x 64 (the CFA phase kept):
    on the whole image it doubled the first image's time (171 s instead of 88 for a 12 MP photograph with the
    learned method); the scores are the method's on the whole images."""
    shapes = []

    def method(raw, pattern="RGGB"):
        shapes.append(tuple(raw.shape[-2:]))
        return demosaic(raw, pattern, "bilinear")

    rng = np.random.default_rng(0)
    items = [("a", rng.integers(0, 256, (150, 130, 3), dtype=np.uint8)),
             ("b", rng.integers(0, 256, (40, 50, 3), dtype=np.uint8))]
    res = evaluate_demosaic(items, method=method)
    assert shapes == [(64, 64), (150, 130), (40, 50)]
    ref = evaluate_demosaic(items, method="bilinear")
    assert [r["cpsnr"] for r in res["images"]] == [r["cpsnr"] for r in ref["images"]]
