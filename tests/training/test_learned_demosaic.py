"""isettorch.isp.learned: the MHC base against colour-demosaicing, the network's residual design, the shipped
checkpoint against Malvar-He-Cutler on benchmark crops, and the demosaic registry hook."""

from pathlib import Path

import numpy as np
import pytest
import torch
from shared_paths import DATA

from isettorch.isp import learned
from isettorch.isp.demosaicing import demosaic_malvar2004
from isettorch.isp.learned import DemosaicNet, demosaic_learned

cd = pytest.importorskip("colour_demosaicing")
KODAK = DATA / "kodak24"
MCM = DATA / "mcmaster18"


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_mirror_boundary_malvar_matches_colour_demosaicing(pattern):
    # The networks' MHC base extends the mosaic by whole-sample mirroring (scipy 'mirror'): colour-demosaicing on
    # the mosaic mirror-padded by 2 px (numpy 'reflect', the Bayer phase kept), cropped back, is the reference
    # at every pixel, borders included.
    img = np.random.default_rng(0).random((12, 16, 3))
    m = cd.mosaicing_CFA_Bayer(img, pattern)
    ref = cd.demosaicing_CFA_Bayer_Malvar2004(np.pad(m, 2, mode="reflect"), pattern)[2:-2, 2:-2]
    out = demosaic_malvar2004(torch.from_numpy(m)[None, None], pattern, boundary="mirror")
    np.testing.assert_allclose(out[0].permute(1, 2, 0).numpy(), ref, atol=1e-12)


def test_untrained_network_is_mhc_and_keeps_known_samples_trainable():
    torch.manual_seed(0)
    raw = torch.rand(2, 1, 16, 20)
    net = DemosaicNet(channels=8, depth=2)
    torch.testing.assert_close(net(raw), demosaic_malvar2004(raw, boundary="mirror"), rtol=0, atol=1e-6)
    # the last layer starts at zero, but its gradient does not vanish (training can leave MHC)
    loss = (net(raw) - torch.rand(2, 3, 16, 20)).abs().mean()
    loss.backward()
    assert net.head.weight.grad.abs().sum() > 0


def test_deep_body_keeps_activation_scale():
    # He et al. (ICCV 2015): with kaiming-normal weights a ReLU conv layer keeps E[x^2] of its input, so the mean
    # square after 11 more layers stays near the first layer's (PyTorch's default init loses ~3x per layer, which
    # left an 8-deep zero-headed network stuck at MHC for hundreds of steps).
    torch.manual_seed(0)
    net = DemosaicNet(channels=64, depth=12)
    x = torch.cat([torch.nn.functional.pixel_unshuffle(torch.rand(2, 1, 64, 64), 2)] * 4, 1)
    first = net.body[1](net.body[0](x)).pow(2).mean()
    last = net.body(x).pow(2).mean()
    assert 0.25 < float(last / first) < 4.0


def test_patterns_are_shifts_of_rggb():
    # A GRBG mosaic of an image is the RGGB mosaic of the image shifted by one column: away from the borders the
    # learned demosaic of both must give the same RGB.
    torch.manual_seed(1)
    net = DemosaicNet(channels=8, depth=2)
    torch.nn.init.normal_(net.head.weight, std=0.05)
    img = torch.rand(1, 3, 24, 26, dtype=torch.float64)
    net = net.double()
    grbg = cd.mosaicing_CFA_Bayer(img[0].permute(1, 2, 0).numpy(), "GRBG")
    rggb = cd.mosaicing_CFA_Bayer(img[0, :, :, 1:-1].permute(1, 2, 0).numpy(), "RGGB")
    a = demosaic_learned(torch.from_numpy(grbg)[None, None], "GRBG", model=net)
    b = demosaic_learned(torch.from_numpy(rggb)[None, None], "RGGB", model=net)
    torch.testing.assert_close(a[..., 8:-8, 9:-9], b[..., 8:-8, 8:-8])


def test_bad_inputs():
    with pytest.raises(ValueError, match="pattern"):
        demosaic_malvar2004(torch.rand(1, 1, 8, 8), "RGBW")
    with pytest.raises(ValueError, match="raw"):
        demosaic_malvar2004(torch.rand(1, 3, 8, 8))
    # the learned entry checks its pattern as every demosaicker does (a second check had raised ValueError for a
    # non-string pattern where demosaic() raised TypeError)
    with pytest.raises(ValueError, match="pattern: expected one of"):
        demosaic_learned(torch.rand(1, 1, 8, 8), "RGBW")
    with pytest.raises(TypeError, match="pattern: expected one of .* as a string"):
        demosaic_learned(torch.rand(1, 1, 8, 8), 1)
    with pytest.raises(ValueError, match="boundary"):
        demosaic_malvar2004(torch.rand(1, 1, 8, 8), boundary="wrap")
    with pytest.raises(ValueError, match="raw"):
        DemosaicNet(channels=4, depth=1)(torch.rand(1, 1, 7, 8))
    with pytest.raises(FileNotFoundError, match="path"):
        learned.load_checkpoint("/nonexistent/ckpt.pt")


def _cpsnr(a, b):
    return float(10 * torch.log10(1 / (a.clamp(0, 1) - b).pow(2).mean()))


def _crops(folder, n, size=128):
    from PIL import Image

    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in (".png", ".tif"))[:n]
    out = []
    for p in files:
        a = np.asarray(Image.open(p).convert("RGB"), dtype=np.float32) / 255.0
        h, w = a.shape[0] // 2 - size // 2, a.shape[1] // 2 - size // 2
        h, w = h - h % 2, w - w % 2
        out.append(torch.from_numpy(a[h:h + size, w:w + size]).permute(2, 0, 1))
    return torch.stack(out)


@pytest.mark.skipif(not learned.PRETRAINED_PATH.is_file(), reason="no shipped checkpoint")
@pytest.mark.parametrize("folder", [KODAK, MCM])
def test_shipped_checkpoint_beats_malvar_on_benchmark_crops(folder):
    if not folder.is_dir():
        pytest.skip(f"{folder} not available")
    img = _crops(folder, 4)
    raw = torch.from_numpy(np.stack([cd.mosaicing_CFA_Bayer(i.permute(1, 2, 0).numpy(), "RGGB") for i in img]))
    raw = raw[:, None].float()
    c = 10
    mhc = _cpsnr(demosaic_malvar2004(raw)[..., c:-c, c:-c], img[..., c:-c, c:-c])
    ours = _cpsnr(demosaic_learned(raw)[..., c:-c, c:-c], img[..., c:-c, c:-c])
    assert ours > mhc + 0.3, (ours, mhc)


@pytest.mark.skipif(not learned.PRETRAINED_PATH.is_file(), reason="no shipped checkpoint")
def test_shipped_checkpoint_loads_safely_and_has_record():
    ck = torch.load(learned.PRETRAINED_PATH, map_location="cpu", weights_only=True)
    assert set(ck) >= {"model", "net_config"}
    info = learned.pretrained_info()
    assert {"command", "config", "wall_s", "hardware", "data"} <= set(info)
    net = learned.load_pretrained()
    assert not any(p.requires_grad for p in net.parameters())
    shipped = sorted(learned.PRETRAINED_PATH.parent.glob("demosaic_learned*.pt"))
    # the noise-free, joint, small and tiny models, nothing else: each at most 4 MB (issue #15)
    assert sorted(shipped) == sorted(learned.PRETRAINED.values())
    assert all(f.stat().st_size <= 4_000_000 for f in shipped), [(f.name, f.stat().st_size) for f in shipped]


@pytest.mark.skipif(not learned.PRETRAINED_PATH.is_file(), reason="no shipped checkpoint")
def test_registered_as_demosaic_method():
    dm = pytest.importorskip("isettorch.isp.demosaicing")
    raw = torch.rand(1, 1, 16, 16)
    out = dm.demosaic(raw, "RGGB", method="learned")
    torch.testing.assert_close(out, demosaic_learned(raw, "RGGB"))


@pytest.mark.skipif(not learned.PRETRAINED_PATH.is_file(), reason="no shipped checkpoint")
def test_usable_as_the_camera_demosaic():
    # The default camera (GRBG sensor) with demosaic: learned renders a Macbeth chart like the Malvar camera does.
    camera_mod = pytest.importorskip("isettorch.camera")
    macbeth = pytest.importorskip("isettorch.scene.macbeth")
    import yaml

    cfg = yaml.safe_load((Path(__file__).resolve().parents[2] / "configs" / "cameras" / "default.yaml").read_text())
    cfg["camera"]["noise"] = False
    scene = macbeth.macbeth("D65", patch_size=8)
    outs = {}
    for method in ("learned", "malvar2004"):
        cfg["isp"]["demosaic"] = method
        cam = camera_mod.Camera.from_config(cfg)
        with torch.no_grad():
            outs[method] = cam(scene)
    a, b = outs["learned"], outs["malvar2004"]
    assert torch.isfinite(a).all() and a.shape == b.shape
    c = 6
    assert (a - b)[..., c:-c, c:-c].abs().mean() < 0.02


@pytest.mark.skipif(not learned.PRETRAINED["joint_denoise"].is_file(), reason="no shipped denoise checkpoint")
def test_joint_denoise_checkpoint_beats_malvar_on_noisy_crops():
    # Kodak crops with Poisson-Gaussian noise var = a x + b (gain 16 on a 10000 e- full well, 3 e- read noise):
    # the joint network, told (a, b), must beat MHC on the noisy mosaic against the clean image.
    if not KODAK.is_dir():
        pytest.skip("Kodak not available")
    img = _crops(KODAK, 3)
    raw = torch.from_numpy(np.stack([cd.mosaicing_CFA_Bayer(i.permute(1, 2, 0).numpy(), "RGGB") for i in img]))
    raw = raw[:, None].float()
    a, b = 16 / 10000, (3 * 16 / 10000) ** 2
    g = torch.Generator().manual_seed(0)
    noisy = raw + torch.sqrt(a * raw + b) * torch.randn(raw.shape, generator=g)
    net = learned.load_pretrained("joint_denoise")
    feats = torch.tensor([[a ** 0.5 * 10, b ** 0.5 * 100]]).expand(len(img), 2)
    ours = _cpsnr(demosaic_learned(noisy, "RGGB", model=net, noise=feats), img)
    mhc = _cpsnr(demosaic_malvar2004(noisy), img)
    assert ours > mhc + 1.0, (ours, mhc)
    with pytest.raises(ValueError, match="variant"):
        learned.load_pretrained("nope")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("variant", ["noise_free", "joint_denoise"])
def test_shipped_models_on_cuda_match_cpu(variant):
    # Each shipped network runs on CUDA (loaded there by default when the mosaic is there) and gives the CPU's
    # output: float32 with TF32 off, so both devices round each convolution in float32; a GRBG mosaic also checks
    # the pattern shift and padding on the device.
    if not learned.PRETRAINED[variant].is_file():
        pytest.skip(f"no shipped {variant} checkpoint")
    g = torch.Generator().manual_seed(5)
    raw = torch.nn.functional.avg_pool2d(torch.rand(2, 1, 68, 100, generator=g), 5, 1)  # (2, 1, 64, 96), smooth
    noise = learned.noise_features(1e-3, 1e-4).float().expand(2, 2) if variant == "joint_denoise" else None
    cpu_net = learned.load_pretrained(variant)
    cpu = demosaic_learned(raw, "GRBG", model=cpu_net, noise=noise)
    tf32 = torch.backends.cudnn.allow_tf32
    torch.backends.cudnn.allow_tf32 = False
    try:
        if variant == "noise_free":
            gpu = demosaic_learned(raw.cuda(), "GRBG")  # default model: loaded on the mosaic's device
        else:
            gpu = demosaic_learned(raw.cuda(), "GRBG", model=learned.load_pretrained(variant, device="cuda"),
                                   noise=noise.cuda())
    finally:
        torch.backends.cudnn.allow_tf32 = tf32
    assert gpu.device.type == "cuda" and gpu.dtype == torch.float32
    assert (cpu - raw.mean()).abs().mean() > 0.01  # the outputs compared are images, not zeros
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=0, atol=1e-4)


def test_self_ensemble_is_the_mean_of_both_passes_and_transpose_equivariant():
    """self_ensemble: the mean of the network on the mosaic and (transposed back) on its transpose, computed here
    by hand; the result is exactly transpose-equivariant, which one pass of a random network is not. For BGGR the
    transposed RGGB-aligned mosaic is still RGGB (the pad is symmetric)."""
    torch.manual_seed(3)
    net = DemosaicNet(channels=8, depth=3, residual=True).double()
    torch.nn.init.normal_(net.head.weight, std=0.05)
    raw = torch.rand(2, 1, 20, 16, dtype=torch.float64)
    with torch.no_grad():
        one = demosaic_learned(raw, "RGGB", model=net)
        two = demosaic_learned(raw, "RGGB", model=net, self_ensemble=True)
        by_hand = 0.5 * (net(raw) + net(raw.mT).mT)
        torch.testing.assert_close(two, by_hand, rtol=0, atol=1e-14)
        swapped = demosaic_learned(raw.mT, "RGGB", model=net, self_ensemble=True)
        torch.testing.assert_close(swapped, two.mT, rtol=0, atol=1e-14)
        assert float((demosaic_learned(raw.mT, "RGGB", model=net) - one.mT).abs().max()) > 1e-4
        bggr = demosaic_learned(raw, "BGGR", model=net, self_ensemble=True)
        padded = torch.nn.functional.pad(raw, (1, 1, 1, 1), mode="reflect")
        torch.testing.assert_close(bggr, (0.5 * (net(padded) + net(padded.mT).mT))[..., 1:-1, 1:-1], rtol=0,
                                   atol=1e-14)
    with pytest.raises(ValueError, match="self_ensemble"):
        demosaic_learned(raw, "RGGB", model=net, self_ensemble=1)
    with pytest.raises(ValueError, match="self_ensemble"):
        demosaic_learned(raw, "RGGB", model=net, self_ensemble="rotate")


def test_dihedral_self_ensemble_is_the_mean_over_flips_and_transposes():
    """self_ensemble="dihedral": the mean over the eight symmetries of the square, computed here by hand: a flipped
    RGGB mosaic is GRBG (columns), GBRG (rows) or BGGR (both); each is reflect-padded by one pixel on the flipped axes
    so it starts with R again, run through the network and its transpose, cropped and flipped back. The result is
    exactly transpose-equivariant and differs from the two-pass ensemble for a network that is not flip-equivariant."""
    torch.manual_seed(5)
    net = DemosaicNet(channels=8, depth=3, residual=True).double()
    torch.nn.init.normal_(net.head.weight, std=0.05)
    raw = torch.rand(2, 1, 20, 16, dtype=torch.float64)
    F = torch.nn.functional

    def two(x):
        return 0.5 * (net(x) + net(x.mT).mT)

    with torch.no_grad():
        outs = [two(raw),
                two(F.pad(raw.flip(-1), (1, 1, 0, 0), mode="reflect"))[..., 1:-1].flip(-1),
                two(F.pad(raw.flip(-2), (0, 0, 1, 1), mode="reflect"))[..., 1:-1, :].flip(-2),
                two(F.pad(raw.flip(-2, -1), (1, 1, 1, 1), mode="reflect"))[..., 1:-1, 1:-1].flip(-2, -1)]
        by_hand = sum(outs) / 4
        eight = demosaic_learned(raw, "RGGB", model=net, self_ensemble="dihedral")
        torch.testing.assert_close(eight, by_hand, rtol=0, atol=1e-14)
        torch.testing.assert_close(demosaic_learned(raw.mT, "RGGB", model=net, self_ensemble="dihedral"), eight.mT,
                                   rtol=0, atol=1e-14)
        assert float((eight - two(raw)).abs().max()) > 1e-4
        assert demosaic_learned(raw, "RGGB", model=net, self_ensemble="transpose").equal(two(raw))


def test_self_ensemble_through_evaluation_and_cli(tmp_path, capsys):
    """evaluate_demosaic and demosaic-eval --self-ensemble run the two-pass learned method (a DemosaicNet file),
    name it, and refuse it for a classical method."""
    import json

    from PIL import Image

    from isettorch.cli import main
    from isettorch.isp.evaluation import evaluate_demosaic

    torch.manual_seed(4)
    net = DemosaicNet(channels=8, depth=3, residual=True)
    torch.nn.init.normal_(net.head.weight, std=0.05)
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (24, 20, 3), dtype=np.uint8)).save(tmp_path / "a.png")
    one = evaluate_demosaic(tmp_path, model=net)
    two = evaluate_demosaic(tmp_path, model=net, self_ensemble=True)
    assert two["method"] == "model:DemosaicNet + self-ensemble" and two["mean_cpsnr"] != one["mean_cpsnr"]
    torch.save({"model": net.state_dict(), "net_config": net.config()}, tmp_path / "net.pt")
    assert main(["demosaic-eval", str(tmp_path), "--model", str(tmp_path / "net.pt"), "--self-ensemble", "--json",
                 "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["mean_cpsnr"] == pytest.approx(two["mean_cpsnr"], abs=1e-6)
    assert main(["demosaic-eval", str(tmp_path), "--method", "menon2007", "--self-ensemble"]) == 2
    assert "--self-ensemble" in capsys.readouterr().err
    eight = evaluate_demosaic(tmp_path, model=net, self_ensemble="dihedral")
    assert eight["method"] == "model:DemosaicNet + dihedral self-ensemble"
    assert eight["mean_cpsnr"] not in (one["mean_cpsnr"], two["mean_cpsnr"])
    assert main(["demosaic-eval", str(tmp_path), "--model", str(tmp_path / "net.pt"), "--dihedral-ensemble", "--json",
                 "--quiet"]) == 0
    assert json.loads(capsys.readouterr().out)["mean_cpsnr"] == pytest.approx(eight["mean_cpsnr"], abs=1e-6)
