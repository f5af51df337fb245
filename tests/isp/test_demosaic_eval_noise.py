"""demosaic-eval with noise, classical denoisers, a user's own network, float32 by default and complete method lists
(issue 15 item 4; issue 18 frictions 6 and 8)."""

from __future__ import annotations

import json
import sys

import colour_demosaicing as cd
import numpy as np
import pytest
import torch
from PIL import Image
from torch import nn

from isettorch.cli import main
from isettorch.commands import demosaic_eval as cmd
from isettorch.isp import evaluation as ev
from isettorch.isp import learned
from isettorch.isp.demosaicing import mosaic


def _image(h=48, w=40, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    base = [0.5 + 0.35 * np.sin((3 + c) * x * 2 + (c + 1) * y * 3) for c in range(3)]
    return np.clip(np.stack(base, -1) * 255 + rng.normal(0, 3, (h, w, 3)), 0, 255).round().astype(np.uint8)


def _truth(a):
    return torch.from_numpy(a.astype(np.float64) / 255).permute(2, 0, 1)[None]


def _numpy_cpsnr(out, truth, crop=0):
    sl = slice(crop, -crop if crop else None)
    err = np.clip(out, 0, 1)[..., sl, sl] - truth[..., sl, sl]
    return 10 * np.log10(1 / np.mean(err**2))


# --- noise --------------------------------------------------------------------------------------------------------

def test_gaussian_noise_statistics_and_seeding():
    raw = torch.full((1, 1, 256, 256), 0.4, dtype=torch.float64)
    n1 = ev.noisy_mosaic(raw, 0.02, seed=3, index=1) - raw
    # sample std of 65536 normal draws: relative standard error 1/sqrt(2 N) = 0.28 %; 5 sigma = 1.4 %
    assert float(n1.std()) == pytest.approx(0.02, rel=0.014)
    assert abs(float(n1.mean())) < 5 * 0.02 / 256
    assert torch.equal(n1, ev.noisy_mosaic(raw, 0.02, seed=3, index=1) - raw)  # seeded by (seed, index)
    assert not torch.equal(n1, ev.noisy_mosaic(raw, 0.02, seed=3, index=2) - raw)
    assert not torch.equal(n1, ev.noisy_mosaic(raw, 0.02, seed=4, index=1) - raw)
    n32 = ev.noisy_mosaic(raw.float(), 0.02, seed=3, index=1) - raw.float()  # the same draws in float32
    torch.testing.assert_close(n32.double(), n1, atol=1e-6, rtol=0)
    assert ev.noisy_mosaic(raw, 0.0) is raw


@pytest.mark.parametrize("level", [0.1, 0.6])
def test_poisson_gaussian_variance_is_ax_plus_b(level):
    a, s = 1e-3, 0.01  # 1000 electrons at white
    raw = torch.full((1, 1, 256, 256), level, dtype=torch.float64)
    noise = ev.noisy_mosaic(raw, s, a, seed=0) - raw
    var = a * level + s * s  # Foi et al. 2008
    assert float(noise.var()) == pytest.approx(var, rel=0.03)  # 5.5 standard errors of a variance of 65536 draws
    assert abs(float(noise.mean())) < 5 * var**0.5 / 256


def test_noise_errors_name_the_argument():
    raw = torch.zeros(1, 1, 8, 8)
    with pytest.raises(ValueError, match="noise_sigma.*-0.1"):
        ev.noisy_mosaic(raw, -0.1)
    with pytest.raises(ValueError, match="noise_shot.*nan"):
        ev.noisy_mosaic(raw, 0.0, float("nan"))


def test_noisy_scores_agree_with_colour_demosaicing():
    a = _image()
    raw = ev.noisy_mosaic(mosaic(_truth(a), "RGGB"), 0.02, seed=5, index=0)
    ref = cd.demosaicing_CFA_Bayer_Malvar2004(raw[0, 0].numpy(), "RGGB").transpose(2, 0, 1)
    res = ev.evaluate_demosaic([("a", a)], "malvar2004", crop=2, noise_sigma=0.02, seed=5, dtype=torch.float64)
    assert res["mean_cpsnr"] == pytest.approx(_numpy_cpsnr(ref, _truth(a)[0].numpy(), 2), abs=1e-9)
    clean = ev.evaluate_demosaic([("a", a)], "malvar2004", crop=2, dtype=torch.float64)["mean_cpsnr"]
    assert res["mean_cpsnr"] < clean - 3  # sigma 0.02 (34 dB) costs several dB here


# --- classical denoisers --------------------------------------------------------------------------------------------

def _assert_nlmeans_per_plane(raw, out, sigma=0.05):
    """``out`` is scikit-image's nlmeans of each CFA sub-plane of ``raw`` (the library's settings for ``sigma``)."""
    from skimage.restoration import denoise_nl_means

    x = raw[0, 0].numpy()
    for dy in (0, 1):
        for dx in (0, 1):
            ref = denoise_nl_means(x[dy::2, dx::2], h=0.6 * sigma, sigma=sigma, patch_size=5, patch_distance=6,
                                   fast_mode=True).reshape(x[dy::2, dx::2].shape)
            np.testing.assert_allclose(out[0, 0, dy::2, dx::2].numpy(), ref, rtol=0, atol=1e-12)


def test_nlmeans_is_scikit_image_per_cfa_plane():
    a = _image(40, 36, seed=1)
    raw = ev.noisy_mosaic(mosaic(_truth(a), "RGGB"), 0.05, seed=0)
    out = ev.denoise_mosaic(raw, "nlmeans", 0.05)
    _assert_nlmeans_per_plane(raw, out)
    clean = mosaic(_truth(a), "RGGB")
    gain = 10 * np.log10(float(((raw - clean) ** 2).mean()) / float(((out - clean) ** 2).mean()))
    assert gain > 3, gain
    # an odd height and width (photographs come so): the same per-plane scikit-image call on shorter planes
    odd = raw[..., :39, :35]
    _assert_nlmeans_per_plane(odd, ev.denoise_mosaic(odd, "nlmeans", 0.05))
    # three columns: two of the planes are one column wide (scikit-image returned them 1-D, which raised a numpy
    # broadcast error)
    thin = raw[..., :12, :3]
    _assert_nlmeans_per_plane(thin, ev.denoise_mosaic(thin, "nlmeans", 0.05))


def test_anscombe_stabilises_poisson_gaussian_variance():
    a, b = 2e-3, 1e-4
    g = torch.Generator().manual_seed(0)
    from isettorch.isp.denoise import _anscombe, _anscombe_inverse
    from isettorch.sensor.noise import poisson_gaussian

    for level in (0.05, 0.3, 0.9):
        x = torch.full((200_000,), level, dtype=torch.float64)
        z = poisson_gaussian(x, a, b**0.5, g).numpy()
        assert np.var(_anscombe(z, a, b)) == pytest.approx(1.0, abs=0.03)  # Makitalo & Foi 2013: ~1
        # the algebraic inverse of the transformed samples' mean (what a denoiser's output estimates) is the level
        # less a / 4 (E[f]^2 = f(E)^2 - 1; Makitalo & Foi 2013, section III), as its docstring says
        assert _anscombe_inverse(np.mean(_anscombe(z, a, b)), a, b) == pytest.approx(level - a / 4, abs=0.05 * a)
    y = np.linspace(0.1, 0.9, 9)  # and exact on noise-free values
    np.testing.assert_allclose(_anscombe_inverse(_anscombe(y, a, b), a, b), y, atol=1e-12)


def test_denoise_improves_the_sequential_baseline():
    a = _image(64, 64, seed=2)
    kw = dict(crop=4, noise_sigma=0.05, seed=1)
    plain = ev.evaluate_demosaic([("a", a)], "malvar2004", **kw)["mean_cpsnr"]
    den = ev.evaluate_demosaic([("a", a)], "malvar2004", denoise="nlmeans", **kw)
    assert den["denoise"] == "nlmeans" and den["mean_cpsnr"] > plain + 2


def test_denoise_errors():
    ims = [("a", _image(16, 16))]
    with pytest.raises(ValueError, match="denoise.*needs noise"):
        ev.evaluate_demosaic(ims, "bilinear", denoise="nlmeans")
    with pytest.raises(ValueError, match="denoise.*nlmeans.*'wiener'"):
        ev.evaluate_demosaic(ims, "bilinear", denoise="wiener", noise_sigma=0.01)
    with pytest.raises(ValueError, match="denoise.*learned"):
        ev.evaluate_demosaic(ims, "learned", denoise="nlmeans", noise_sigma=0.01)


@pytest.mark.parametrize("method", ["learned_small", "learned_tiny"])
def test_the_noise_free_networks_take_the_denoised_mosaic(method):
    # learned_small and learned_tiny are noise-free networks (only 'learned' switches to the joint one with noise):
    # they were refused a denoiser ('the learned method denoises itself'), so nlmeans-then-network could not be
    # scored. Denoised, they score above the network on the noisy mosaic, as the classical methods do.
    a = _image(64, 64, seed=2)
    kw = dict(crop=4, noise_sigma=0.05, seed=1)
    plain = ev.evaluate_demosaic([("a", a)], method, **kw)
    den = ev.evaluate_demosaic([("a", a)], method, denoise="nlmeans", **kw)
    assert den["denoise"] == "nlmeans" and den["network"] is None
    assert den["mean_cpsnr"] > plain["mean_cpsnr"] + 2


def test_noise_levels_whose_variance_overflows_are_refused():
    ims = [("a", _image(16, 16))]
    # sigma^2 of 1e300 overflows a float (max ~1.8e308), as does the a^2 of the Anscombe transform for a = 1e200
    with pytest.raises(ValueError, match=r"noise_sigma: expected a standard deviation whose square"):
        ev.evaluate_demosaic(ims, "bilinear", noise_sigma=1e300)
    with pytest.raises(ValueError, match=r"noise_shot: expected a shot-noise gain whose square"):
        ev.evaluate_demosaic(ims, "bilinear", noise_shot=1e200)
    raw = torch.full((1, 1, 4, 4), 0.5, dtype=torch.float64)
    with pytest.raises(ValueError, match="noise_sigma"):
        ev.noisy_mosaic(raw, 1e300)
    # the joint network's noise inputs: sqrt(a) * 10 and sqrt(b) * 100 (a = 0.04, b = 1e-4: 2 and 1)
    torch.testing.assert_close(learned.noise_features(0.04, 1e-4), torch.tensor([[2.0, 1.0]], dtype=torch.float64))
    for a, b, name in ((float("inf"), 0.0, "shot_gain"), (0.0, float("inf"), "read_var"),
                       (torch.tensor([0.1, float("nan")]), 0.0, "shot_gain")):
        with pytest.raises(ValueError, match=f"{name}: expected finite noise parameters, found 1 NaN/inf"):
            learned.noise_features(a, b)


def test_bm3d_missing_is_named_before_any_work(monkeypatch):
    monkeypatch.setitem(sys.modules, "bm3d", None)  # `import bm3d` now fails as when the package is absent
    calls = []
    with pytest.raises(ValueError, match=r"^denoise: 'bm3d' needs the bm3d package"):
        ev.evaluate_demosaic([("a", _image(16, 16))], lambda raw, p: calls.append(1), denoise="bm3d",
                             noise_sigma=0.05)
    assert calls == []


def test_bm3d_optional():
    bm3d = pytest.importorskip("bm3d")
    raw = ev.noisy_mosaic(mosaic(_truth(_image(32, 32)), "RGGB"), 0.05)
    out = ev.denoise_mosaic(raw, "bm3d", 0.05)
    ref = bm3d.bm3d(raw[0, 0, 0::2, 0::2].numpy(), sigma_psd=0.05)
    np.testing.assert_allclose(out[0, 0, 0::2, 0::2].numpy(), ref, atol=1e-9)


# --- learned: joint model under noise; float32 by default -----------------------------------------------------------

def test_learned_uses_joint_model_given_the_noise_level():
    a = _image(32, 32, seed=3)
    res = ev.evaluate_demosaic([("a", a)], "learned", noise_sigma=0.02, seed=2)
    raw = ev.noisy_mosaic(mosaic(_truth(a), "RGGB").float(), 0.02, seed=2, index=0)
    net = learned.load_pretrained("joint_denoise")
    with torch.no_grad():
        out = learned.demosaic_learned(raw, "RGGB", model=net, noise=learned.noise_features(0.0, 0.02**2))
        other = learned.demosaic_learned(raw, "RGGB", model=learned.load_pretrained("noise_free"))
    truth = _truth(a)[0].numpy()
    expect = _numpy_cpsnr(out[0].double().numpy(), truth)
    assert res["mean_cpsnr"] == pytest.approx(expect, abs=1e-6)
    assert res["mean_cpsnr"] != pytest.approx(_numpy_cpsnr(other[0].double().numpy(), truth), abs=1e-3)
    # noise features: sqrt(a) * 10, sqrt(b) * 100
    torch.testing.assert_close(learned.noise_features(0.01, 4e-4), torch.tensor([[1.0, 2.0]], dtype=torch.float64))


class _Grey(nn.Module):
    """A float32 'demosaic' whose output is the mosaic in all three channels (CPSNR computable by hand)."""

    def __init__(self):
        super().__init__()
        self.conv = nn.Conv2d(1, 3, 1, bias=False)
        nn.init.ones_(self.conv.weight)

    def forward(self, raw):
        return self.conv(raw)


def _grey_cpsnr(a):
    t = _truth(a)[0].numpy()
    m = mosaic(_truth(a), "RGGB")[0].numpy()
    return _numpy_cpsnr(np.repeat(m, 3, 0), t)


def test_float32_network_runs_by_default():
    a = _image(24, 24)
    net = _Grey()  # float32 parameters: a float64 mosaic raised "Input type (double) and bias type (float)"
    res = ev.evaluate_demosaic([("a", a)], lambda raw, pattern: net(raw))
    assert res["dtype"] == "float32"
    assert res["mean_cpsnr"] == pytest.approx(_grey_cpsnr(a), abs=1e-4)


def test_method_errors_name_every_method_learned_included():
    assert "learned" in ev.available_methods()
    with pytest.raises(ValueError) as err:
        ev.evaluate_demosaic([("a", _image(16, 16))], "nope")
    for name in ev.available_methods():
        assert repr(name) in str(err.value)
    assert set(cmd.METHOD_NAMES) == set(ev.available_methods())  # the CLI help's static list
    assert tuple(cmd.DENOISER_NAMES) == ev.DENOISERS


# --- --model -------------------------------------------------------------------------------------------------------

@pytest.fixture
def folder(tmp_path):
    d = tmp_path / "ims"
    d.mkdir()
    a = _image(24, 28, seed=4)
    Image.fromarray(a).save(d / "a.png")
    return d, a


def _cli_json(capsys, *args):
    assert main(["demosaic-eval", *map(str, args), "--json", "--quiet"]) == 0
    return json.loads(capsys.readouterr().out)


def test_model_torchscript(folder, tmp_path, capsys):
    d, a = folder
    path = tmp_path / "grey.ts"
    torch.jit.script(_Grey()).save(str(path))
    res = _cli_json(capsys, d, "--model", path)
    assert res["mean_cpsnr"] == pytest.approx(_grey_cpsnr(a), abs=1e-4)


def test_model_state_dict_with_class_path(folder, tmp_path, capsys, monkeypatch):
    d, a = folder
    (tmp_path / "usernet.py").write_text(
        "import torch\nfrom torch import nn\n\n"
        "class Grey(nn.Module):\n"
        "    def __init__(self, width=1):\n"
        "        super().__init__()\n"
        "        self.conv = nn.Conv2d(width, 3, 1, bias=False)\n\n"
        "    def forward(self, raw):\n"
        "        return self.conv(raw)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    sd = _Grey().state_dict()
    torch.save(sd, tmp_path / "grey.pt")
    res = _cli_json(capsys, d, "--model", tmp_path / "grey.pt", "--model-class", "usernet:Grey",
                    "--model-kwargs", '{"width": 1}')
    assert res["mean_cpsnr"] == pytest.approx(_grey_cpsnr(a), abs=1e-4)
    assert main(["demosaic-eval", str(d), "--model", str(tmp_path / "grey.pt")]) == 2
    assert "--model-class: grey.pt is a state dict" in capsys.readouterr().err
    assert main(["demosaic-eval", str(d), "--model", str(tmp_path / "grey.pt"), "--model-class", "usernet"]) == 2
    assert "--model-class: expected 'package.module:Class', got 'usernet'" in capsys.readouterr().err
    sys.modules.pop("usernet", None)


def test_model_demosaicnet_checkpoint(folder, tmp_path, capsys):
    d, a = folder
    torch.manual_seed(0)
    net = learned.DemosaicNet(channels=4, depth=1)
    nn.init.normal_(net.head.weight, std=0.01)
    torch.save({"model": net.state_dict(), "net_config": net.config()}, tmp_path / "ck.pt")
    res = _cli_json(capsys, d, "--model", tmp_path / "ck.pt")
    with torch.no_grad():
        out = net(mosaic(_truth(a), "RGGB").float())
    assert res["mean_cpsnr"] == pytest.approx(_numpy_cpsnr(out[0].double().numpy(), _truth(a)[0].numpy()), abs=1e-5)


def test_model_refuses_pickled_objects(folder, tmp_path, capsys):
    d, _ = folder
    torch.save({"net": _Grey()}, tmp_path / "pickled.pt")  # a whole module: needs unpickling arbitrary classes
    with pytest.raises(ValueError, match="neither a TorchScript archive nor a weights-only state dict"):
        ev.load_demosaic_model(tmp_path / "pickled.pt")
    assert main(["demosaic-eval", str(d), "--model", str(tmp_path / "pickled.pt")]) == 2
    assert "--model: " in capsys.readouterr().err
    assert main(["demosaic-eval", str(d), "--model", str(tmp_path / "missing.pt")]) == 2
    assert "--model: no such file" in capsys.readouterr().err


def test_progress_bar_and_quiet(folder, capsys):
    d, _ = folder
    assert main(["demosaic-eval", str(d), "--method", "bilinear"]) == 0
    assert "demosaic-eval bilinear" in capsys.readouterr().err
    for flag in ("--quiet", "-q"):
        assert main(["demosaic-eval", str(d), "--method", "bilinear", flag]) == 0
        assert capsys.readouterr().err == ""


def test_cli_noise_flags(folder, capsys):
    """--noise-sigma / --noise-shot / --seed / --denoise reach evaluate_demosaic: the CLI's score equals the API's."""
    d, a = folder
    res = _cli_json(capsys, d, "--method", "malvar2004", "--noise-sigma", "0.01", "--noise-shot", "0.002",
                    "--seed", "3", "--denoise", "nlmeans")
    assert (res["noise_sigma"], res["noise_shot"], res["seed"], res["denoise"]) == (0.01, 0.002, 3, "nlmeans")
    api = ev.evaluate_demosaic([("a.png", a)], "malvar2004", noise_sigma=0.01, noise_shot=0.002, seed=3,
                               denoise="nlmeans")
    assert res["mean_cpsnr"] == pytest.approx(api["mean_cpsnr"], abs=1e-9)
    noisy = _cli_json(capsys, d, "--method", "malvar2004", "--noise-sigma", "0.01", "--noise-shot", "0.002",
                      "--seed", "3")
    assert noisy["denoise"] is None and noisy["mean_cpsnr"] != pytest.approx(res["mean_cpsnr"], abs=1e-3)
    assert main(["demosaic-eval", str(d), "--model-class", "a:B"]) == 2
    assert "--model-class/--model-kwargs: only with --model" in capsys.readouterr().err


def test_denoise_and_noisy_mosaic_refuse_what_they_took_silently():
    """denoise_mosaic took a uint8 mosaic (denoised on 0-255 and truncated), a NaN sample (spread over its search
    window), noise_sigma=True (1.0) and "0.1"; noisy_mosaic a fractional seed (1.5 was 1) and a NaN raw (torch's
    'invalid Poisson rate', naming nothing)."""
    from isettorch.isp.denoise import denoise_mosaic
    from isettorch.isp.evaluation import noisy_mosaic

    raw = torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    bad = raw.clone()
    bad[0, 0, 3, 3] = float("nan")
    cases = ((lambda: denoise_mosaic((raw * 255).to(torch.uint8), "nlmeans", 2.0), TypeError, "raw: expected a floa"),
             (lambda: denoise_mosaic(bad, "nlmeans", 0.01), ValueError, "raw: expected finite"),
             (lambda: denoise_mosaic(raw, "nlmeans", True), TypeError, "noise_sigma: expected a number"),
             (lambda: denoise_mosaic(raw, "nlmeans", "0.1"), TypeError, "noise_sigma: expected a number"),
             (lambda: noisy_mosaic(raw, 0.01, seed=1.5), TypeError, "seed: expected an integer"),
             (lambda: noisy_mosaic(bad, 0.01, 0.01), ValueError, "raw: expected finite"))
    for call, error, message in cases:
        with pytest.raises(error, match=message):
            call()
    assert torch.equal(noisy_mosaic(raw, 0.01, seed=3), noisy_mosaic(raw, 0.01, seed=3))


def test_denoiser_edge_cases_found_by_the_denoise_audit(tmp_path, monkeypatch):
    """Shot noise far below the Gaussian floor (a = 1e-20 beside sigma 0.02) lost the signal in the Anscombe
    transform (values 129 off): denoised as the Gaussian noise it is; shot noise on a negative mosaic named
    poisson_gaussian's 'signal'; bm3d installed without its dependency said 'needs the bm3d package'. (A bound
    refusing 0-255 float mosaics was tried and removed: the joint network's classical expert gets bright, white-
    balanced highlights above 1.5 legitimately.)"""
    truth = mosaic(_truth(_image(32, 32)), "RGGB")
    raw = ev.noisy_mosaic(truth, 0.02, 1e-20, seed=3)
    torch.testing.assert_close(ev.denoise_mosaic(raw, "nlmeans", 0.02, 1e-20), ev.denoise_mosaic(raw, "nlmeans", 0.02),
                               rtol=0, atol=1e-12)
    assert float((ev.denoise_mosaic(raw, "nlmeans", 0.02, 1e-20) - truth).abs().max()) < 0.2
    with pytest.raises(ValueError, match=r"raw: expected values >= 0 for shot noise \(noise_shot 0.01 > 0\)"):
        ev.noisy_mosaic(truth - 0.5, 0.0, 0.01)
    fake = tmp_path / "bm3d"
    fake.mkdir()
    (fake / "__init__.py").write_text("import bm4d_not_installed_here\n")  # as bm3d without its bm4d
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "bm3d", raising=False)
    with pytest.raises(ValueError, match=r"'bm3d' is installed but cannot be imported: its dependency "
                                         r"'bm4d_not_installed_here' is missing"):
        ev.denoise_mosaic(raw, "bm3d", 0.02)


def test_the_learned_method_refuses_a_variant_it_would_ignore():
    """evaluate_demosaic(..., "learned", variant="tiny") scored the default network, labelled noise_free."""
    with pytest.raises(ValueError, match=r"variant: the learned method scores the shipped default network.*"
                                         r"'learned_tiny', got variant 'tiny'"):
        ev.evaluate_demosaic([("a", _image(16, 16))], "learned", variant="tiny")
