"""training/train_demosaic.py: smoke run, exact resume, reproducible batches, CPSNR convention, torchrun DDP."""

import csv
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from isettorch.isp import learned  # noqa: E402
from isettorch.isp.learned import demosaic_learned  # noqa: E402
from training import common, demosaic_data, train_demosaic  # noqa: E402

SMOKE = ROOT / "configs" / "train" / "demosaic_smoke.yaml"


def test_cpsnr_matches_skimage():
    metrics = pytest.importorskip("skimage.metrics")
    rng = np.random.default_rng(0)
    a = rng.random((3, 20, 24))
    b = np.clip(a + 0.05 * rng.standard_normal(a.shape), 0, 1)
    ref = metrics.peak_signal_noise_ratio(a[:, 3:-3, 3:-3], b[:, 3:-3, 3:-3], data_range=1.0)
    ours = common.cpsnr(torch.from_numpy(b)[None], torch.from_numpy(a)[None], crop=3)
    assert float(ours) == pytest.approx(ref, abs=1e-9)


def test_mosaic_is_rggb():
    rgb = torch.rand(2, 3, 4, 6)
    raw = train_demosaic.mosaic_rggb(rgb)
    assert torch.equal(raw[:, 0, 0::2, 0::2], rgb[:, 0, 0::2, 0::2])
    assert torch.equal(raw[:, 0, 0::2, 1::2], rgb[:, 1, 0::2, 1::2])
    assert torch.equal(raw[:, 0, 1::2, 0::2], rgb[:, 1, 1::2, 0::2])
    assert torch.equal(raw[:, 0, 1::2, 1::2], rgb[:, 2, 1::2, 1::2])


def test_synth_source_is_retired():
    cfg = common.load_config(SMOKE)
    cfg["data"]["source"] = "synth"
    with pytest.raises(ValueError, match="'synth'.*retired.*natural"):
        train_demosaic.make_sampler(cfg)


def test_config_and_overrides_read_exponent_floats_as_numbers(tmp_path):
    """``lr: 1e-3`` in a training config and ``--set optim.lr=1e-3`` are the number 0.001 (YAML 1.2 floats, the
    library's reader; PyYAML's safe_load gives the string '1e-3', which the optimiser would reject)."""
    path = tmp_path / "c.yaml"
    path.write_text("optim: {lr: 1e-3, lr_min: 2.5E-5}\nname: '1e-3'\n")
    cfg = common.load_config(path, ["optim.warmup=2e2", "data.batch=8", "out=1e-3x"])
    assert cfg["optim"] == {"lr": 0.001, "lr_min": 2.5e-5, "warmup": 200.0}
    assert cfg["name"] == "1e-3" and cfg["data"] == {"batch": 8} and cfg["out"] == "1e-3x"
    assert isinstance(cfg["data"]["batch"], int)


def test_training_domain_is_explicit():
    """linear: values are the exposed linear image (<= 1, no encoding); encoded: a power 1/gamma of it."""
    cfg = common.load_config(SMOKE)
    batches = {}
    for dom in ("linear", "encoded"):
        cfg["data"]["domain"] = dom
        batches[dom] = train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 5, 4)[1]
    lin, enc = batches["linear"], batches["encoded"]
    # same draws: encoded = linear^(1/gamma) with gamma in [1.8, 2.6] per image, so enc >= lin everywhere
    assert bool((enc >= lin - 1e-6).all()) and float((enc - lin).mean()) > 0.05
    for i in range(4):
        m = (lin[i] > 0.05) & (lin[i] < 0.95)
        gamma = torch.log(lin[i][m]) / torch.log(enc[i][m])
        assert 1.8 - 1e-3 <= float(gamma.median()) <= 2.6 + 1e-3 and float(gamma.std()) < 1e-3
    cfg["data"]["domain"] = "srgb"
    with pytest.raises(ValueError, match="domain.*'srgb'"):
        train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 5, 4)


def test_hard_mining_keeps_the_hardest_crops():
    cfg = common.load_config(SMOKE)
    plain = train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 9, 4)[1]
    cfg["data"]["hard_mining"] = 4
    hard = train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 9, 4)[1]

    def mhc_mse(x):
        return float((train_demosaic.demosaic_malvar2004(train_demosaic.mosaic_rggb(x)) - x).pow(2).mean())

    assert mhc_mse(hard) > mhc_mse(plain)


def test_batches_depend_only_on_seed():
    cfg = common.load_config(SMOKE)
    s = train_demosaic.make_sampler(cfg)
    a = train_demosaic.make_batch(s, cfg, 123, 2)
    b = train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 123, 2)
    c = train_demosaic.make_batch(s, cfg, 124, 2)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert not torch.equal(a[1], c[1])
    assert a[1].min() >= 0 and a[1].max() <= 1


def test_noise_model_variance():
    # var = a x + b (Poisson-Gaussian photon transfer): check the empirical variance of the added noise
    g = torch.Generator().manual_seed(0)
    raw = torch.full((2, 1, 200, 200), 0.25)
    ab = torch.tensor([[1e-3, 1e-5], [4e-3, 0.0]])
    noisy = train_demosaic.add_noise(raw, ab, g)
    var = (noisy - raw).flatten(1).var(1)
    expected = ab[:, 0] * 0.25 + ab[:, 1]
    torch.testing.assert_close(var, expected, rtol=0.03, atol=0)
    # exact Poisson shot noise: counts x / a are integers
    shot = train_demosaic.add_noise(raw[:1], torch.tensor([[1e-3, 0.0]]), g)
    counts = shot.double() / 1e-3  # ~250 electrons, float32 storage: integers to 1e-3
    torch.testing.assert_close(counts, counts.round(), rtol=0, atol=1e-3)
    assert float((counts - counts.round()).abs().max()) < 1e-3 and float(counts.std()) > 10


@pytest.mark.parametrize("batch", [2, 10])
def test_a_batch_that_does_not_split_over_the_processes_is_refused(tmp_path, monkeypatch, batch):
    """Under torchrun each process trains data.batch // world images: 2 over 4 processes was an empty stack, and 10
    over 4 silently trained 8 a step. Both are refused naming data.batch (world size 4 stood in for torchrun)."""
    monkeypatch.setattr(train_demosaic.common, "dist_setup", lambda device: (0, 4, False))
    with pytest.raises(SystemExit, match=rf"data\.batch: {batch} images do not split evenly over 4 processes .*"
                                         rf"expected a multiple of 4"):
        train_demosaic.main(["--config", str(SMOKE), "--out", str(tmp_path / "run"), "--quiet", "--threads", "1",
                             "--steps", "1", "--set", f"data.batch={batch}"])


def test_smoke_training_resume(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["--config", str(SMOKE), "--out", str(out), "--no-progress", "--threads", "1"]
    assert train_demosaic.main(args + ["--steps", "4", "--stop-after", "2"]) == 0
    ck = torch.load(out / "last.pt", map_location="cpu", weights_only=True)
    assert ck["step"] == 2
    assert (out / "best.pt").is_file() and (out / "curves.png").stat().st_size > 1000
    # resume: continues from step 2 to 4 and gives the same weights as an uninterrupted 4-step run
    assert train_demosaic.main(args + ["--steps", "4"]) == 0
    resumed = torch.load(out / "last.pt", map_location="cpu", weights_only=True)
    assert resumed["step"] == 4
    # another run's config is refused (a new seed and lr ran on, mixing the two runs' histories); a longer one is not
    with pytest.raises(SystemExit, match=r"another config \(optim.lr, seed changed\)"):
        train_demosaic.main(args + ["--steps", "6", "--set", "seed=7", "optim.lr=0.05"])
    # a network of another shape too (it was a raw load_state_dict size mismatch, before the config check)
    width = json.loads(resumed["train_config"])["net"]["channels"]
    with pytest.raises(SystemExit, match=r"another config \(net.channels changed\)"):
        train_demosaic.main(args + ["--steps", "6", "--set", f"net.channels={width + 4}"])
    assert train_demosaic.resume_changes(json.loads(resumed["train_config"]),
                                         {**json.loads(resumed["train_config"]), "threads": 2}) == []
    straight = tmp_path / "straight"
    capsys.readouterr()
    assert train_demosaic.main(["--config", str(SMOKE), "--out", str(straight), "--quiet", "--threads", "1",
                                "--steps", "4"]) == 0
    # --quiet (--no-progress above: its former name): no bar on stderr, the validation rows still on stdout
    captured = capsys.readouterr()
    assert "step/s" not in captured.err and "4/4" not in captured.err
    assert [line.split()[0] for line in captured.out.splitlines() if line.startswith("step=")] == ["step=2", "step=4"]
    ref = torch.load(straight / "last.pt", map_location="cpu", weights_only=True)
    for k, v in ref["model"].items():
        torch.testing.assert_close(resumed["model"][k], v, rtol=0, atol=1e-6)
    rows = list(csv.DictReader(open(straight / "history.csv")))
    assert [int(r["step"]) for r in rows] == [2, 4]
    assert [r["lr"] for r in rows] == [r["lr"] for r in csv.DictReader(open(out / "history.csv"))]
    assert all(np.isfinite(float(r["train_loss"])) and float(r["val_cpsnr"]) > 10 for r in rows)
    rec = json.loads((straight / "record.json").read_text())
    assert rec["steps"] == 4 and rec["wall_s"] > 0 and "isettorch.data.natural" in rec["data"]
    assert "cpu_count" in rec["hardware"] and rec["config"]["data"]["source"] == "natural"
    card = (straight / "MODEL_CARD.md").read_text()
    assert "training/train_demosaic.py" in card or "--config" in card
    assert "steps: 4" in card and "never Kodak/McMaster" in card
    # the trained weights moved away from the zero-initialised head
    assert ref["model"]["head.weight"].abs().sum() > 0
    # a stop off the validation steps (step 3) checkpoints without a row of its own, and carries the running loss:
    # the resumed run's history is the uninterrupted one's (an extra row at the stop could move best.pt's choice)
    odd = tmp_path / "odd"
    odd_args = ["--config", str(SMOKE), "--out", str(odd), "--quiet", "--threads", "1", "--steps", "4"]
    assert train_demosaic.main(odd_args + ["--stop-after", "3"]) == 0
    assert [int(r["step"]) for r in csv.DictReader(open(odd / "history.csv"))] == [2]
    assert train_demosaic.main(odd_args) == 0
    for a, b in zip(csv.DictReader(open(odd / "history.csv")), rows, strict=True):
        assert (a["step"], a["train_loss"], a["val_cpsnr"]) == (b["step"], b["train_loss"], b["val_cpsnr"])


def test_config_keys_and_values_are_checked_before_a_run(tmp_path, monkeypatch):
    """A misspelt key ran with its default (optim.lrr, data.batchsize), optim.loss l3 trained with L2,
    checkpoint_every 0 divided by zero later (an audit of training/): refused before anything runs, naming the key.
    Every shipped training config passes, and a config that starts from a shipped model declares its size."""
    args = ["--config", str(SMOKE), "--out", str(tmp_path / "x"), "--quiet", "--threads", "1", "--set"]
    for override, message in (("optim.lrr=0.1", "config.optim.lrr: unknown key"),
                              ("data.batchsize=4", "config.data.batchsize: unknown key"),
                              ("valid={every: 2}", "config.valid: unknown key"),
                              ("optim.loss=l3", "config.optim.loss: expected one of"),
                              ("checkpoint_every=0", "config.checkpoint_every: expected a positive integer"),
                              ("optim.lr=abc", "config.optim.lr: expected a positive number"),
                              ("noise=null", "config.noise: expected a mapping"),
                              # (int('big') failed unnamed; pool 0 in torch.randint; -8 was blamed on data.patch;
                              # negative warmup / refresh and a fraction of 2 ran; gain_min 0 divided by zero)
                              ("data.patch=big", "config.data.patch: expected a positive integer, got 'big'"),
                              ("data.pool=0", "config.data.pool: expected a positive integer, got 0"),
                              ("val.size=-8", "config.val.size: expected a positive integer, got -8"),
                              ("optim.warmup=-5", r"config.optim.warmup: expected an integer >= 0, got -5"),
                              ("data.refresh=-1", r"config.data.refresh: expected an integer >= 0"),
                              ("seed=abc", r"config.seed: expected an integer >= 0, got 'abc'"),
                              ("optim.lr_min=abc", "config.optim.lr_min: expected a positive number"),
                              ("data.encoded_fraction=2", r"config.data.encoded_fraction: expected a fraction in"),
                              ("noise={enabled: true, gain_min: 0}", "config.noise.gain_min: expected a positive"),
                              # (8 failed after val.every steps in the crop check; 33 was blamed on data.patch; a
                              # gaussian_fraction of 2 failed in a tensor expand)
                              ("val.size=8", "config.val.size: expected an even number of pixels >= 10"),
                              ("val.size=33", "config.val.size: expected an even number"),
                              ("noise={enabled: true, gaussian_fraction: 2}",
                               r"config.noise.clean_fraction, config.noise.gaussian_fraction: expected fractions"),
                              ("noise={enabled: true, clean_fraction: -0.5}",
                               r"config.noise.clean_fraction: expected a number >= 0")):
        with pytest.raises(ValueError, match=message):
            train_demosaic.main(args + [override])
    assert not (tmp_path / "x" / "last.pt").exists()
    for bad in ("0", "-2"):  # (0 ran the whole run, -2 did nothing with exit 0)
        with pytest.raises(SystemExit, match=rf"--stop-after: expected a number of steps >= 1, got {bad}"):
            train_demosaic.main(args[:-1] + ["--stop-after", bad])
    # a reporting folder that does not exist stopped the run when its first row fell due (step 10000 of the
    # noise-free config, or the end of a 6000 s run): found before the first step
    def no_step(*a, **k):
        raise AssertionError("a training step ran before the reporting folders were found")

    with monkeypatch.context() as m:
        m.setattr(train_demosaic, "make_batch", no_step)
        with pytest.raises(FileNotFoundError, match="no_such_benchmark"):
            train_demosaic.main(args + ["eval={every: 1000, benchmarks: {kodak: no_such_benchmark}}"])
    from training.demosaic_config import check_config

    for path in sorted((ROOT / "configs" / "train").glob("demosaic_*.yaml")):
        cfg = check_config(common.load_config(path))
        init = cfg.get("init")
        if init and str(init).startswith("isettorch/assets/"):
            shipped = torch.load(ROOT / init, map_location="cpu", weights_only=True)["net_config"]
            for key in ("channels", "depth"):
                assert cfg["net"].get(key) == shipped[key], (path.name, key)


def test_full_sensor_noise_variance_is_ax_plus_b():
    """Shot + dark + DSNU + read + 10-bit quantisation: the empirical variance at two levels is a x + b of
    noise_params (EMVA 1288 photon transfer), PRNU off."""
    cfg = {"noise": {"gain_min": 4.0, "gain_max": 4.0, "full_well_e": 8000.0, "read_noise_e": 2.0, "dsnu_e": 1.5,
                     "dark_e": 9.0, "bits": 10}}
    g = torch.Generator().manual_seed(1)
    ab = train_demosaic.noise_params(2, cfg, g)
    a = 4.0 / 8000
    b = a * a * (4.0 + 2.25 + 9.0) + (1 / 1023) ** 2 / 12
    torch.testing.assert_close(ab, torch.tensor([[a, b], [a, b]]), rtol=1e-6, atol=0)
    raw = torch.stack([torch.full((1, 200, 200), 0.1), torch.full((1, 200, 200), 0.5)])
    noisy = train_demosaic.add_noise(raw, ab, g, cfg["noise"])
    var = (noisy - raw).flatten(1).var(1)
    torch.testing.assert_close(var, a * raw.flatten(1)[:, 0] + b, rtol=0.04, atol=0)
    # quantised to the 10-bit grid (the dark electrons pass the ADC, their mean a * dark_e is subtracted after it);
    # mean preserved (black level and dark frame subtracted)
    codes = (noisy.double() + a * 9.0) * 1023
    torch.testing.assert_close(codes, codes.round(), rtol=0, atol=1e-3)
    torch.testing.assert_close(noisy.flatten(1).mean(1), raw.flatten(1)[:, 0], rtol=0, atol=3e-4)


def test_sensor_noise_per_image_gains_black_and_prnu():
    """add_noise is one isettorch Sensor with per-image [B] levels: four images at their own random gains
    (noise_params, gains 1-64), at black (x = 0: the pedestal keeps read noise and DSNU unclipped, so the mean stays
    0 and the variance is b) and at x = 0.3, each with variance a x + b (EMVA 1288 photon transfer; Foi et al.
    2008); PRNU adds (prnu x)^2 (EMVA 1288 eq. 12); the draw is a function of the generator's seed only."""
    n = {"gain_min": 1.0, "gain_max": 64.0, "full_well_e": 10000.0, "read_noise_e": 3.0, "dsnu_e": 1.0,
         "dark_e": 5.0, "bits": 12}
    g = torch.Generator().manual_seed(5)
    ab = train_demosaic.noise_params(4, {"noise": n}, g)
    assert float(ab[:, 0].max() / ab[:, 0].min()) > 1.5  # distinct gains in one batch
    x = torch.tensor([0.0, 0.3, 0.0, 0.3]).reshape(4, 1, 1, 1)
    raw = x.expand(4, 1, 200, 200).contiguous()
    state = g.get_state()
    noisy = train_demosaic.add_noise(raw, ab, g, n)
    # var of 40000 samples: relative standard error sqrt(2 / n) = 0.7 %
    torch.testing.assert_close(noisy.flatten(1).var(1), ab[:, 0] * x.flatten() + ab[:, 1], rtol=0.04, atol=0)
    torch.testing.assert_close(noisy.flatten(1).mean(1), x.flatten(), rtol=0, atol=1e-3)
    assert torch.equal(train_demosaic.add_noise(raw, ab, torch.Generator().set_state(state), n), noisy)
    # PRNU 2 % redrawn per frame at x = 0.5: + (0.02 x)^2 = 1e-4, about as large as a x at gain 1
    prnu = dict(n, prnu_percent=2.0)
    half = torch.full((4, 1, 200, 200), 0.5)
    var = train_demosaic.add_noise(half, ab, g, prnu).flatten(1).var(1)
    torch.testing.assert_close(var, ab[:, 0] * 0.5 + ab[:, 1] + (0.02 * 0.5) ** 2, rtol=0.04, atol=0)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_torchrun_ddp_two_processes(tmp_path):
    out = tmp_path / "ddp"
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2", "--master_port",
           str(_free_port()), str(ROOT / "training" / "train_demosaic.py"), "--config", str(SMOKE), "--out", str(out),
           "--steps", "2", "--no-progress", "--threads", "1", "--device", "cpu"]
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    rec = json.loads((out / "record.json").read_text())
    assert rec["world_size"] == 2 and rec["steps"] == 2
    assert torch.load(out / "last.pt", map_location="cpu", weights_only=True)["step"] == 2


def test_joint_batches_carry_noise_features():
    cfg = common.load_config(ROOT / "configs" / "train" / "demosaic_joint_denoise.yaml")
    smoke = common.load_config(SMOKE)
    cfg["data"], cfg["val"] = smoke["data"], smoke["val"]
    raw, rgb, feats = train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 3, 4)
    n = cfg["noise"]
    k = round(n["gaussian_fraction"] * 4)
    assert feats.shape == (4, 2) and k == 2 and bool((feats[:, 1] > 0).all())
    noise = raw - train_demosaic.mosaic_rggb(rgb)
    # the first k images: white Gaussian noise (a = 0) of the std in their feature sqrt(b) * 100
    sigma = feats[:k, 1] / 100
    assert bool((feats[:k, 0] == 0).all())
    assert bool(((sigma >= n["sigma_min"] * (1 - 1e-6)) & (sigma <= n["sigma_max"] * (1 + 1e-6))).all())
    torch.testing.assert_close(noise[:k].flatten(1).std(1), sigma, rtol=0.1, atol=0)
    # the others: sensor noise; the features are sqrt(a) * 10, sqrt(b) * 100 of noise_params
    assert float(noise[k:].std()) > 1e-3
    a = (feats[k:, 0] / 10) ** 2
    assert bool(((a >= 1.0 / 10000 * (1 - 1e-5)) & (a <= 64.0 / 10000 * (1 + 1e-5))).all())


def test_clean_fraction_leaves_the_last_images_without_noise():
    """noise.clean_fraction: the last k images of a batch are the exact noise-free mosaic with zero noise
    features (the sigma = 0 case for a joint model of every level), the first ones Gaussian, the middle sensor
    noise; fractions summing above 1 are refused."""
    cfg = common.load_config(ROOT / "configs" / "train" / "demosaic_joint_all_levels.yaml")
    smoke = common.load_config(SMOKE)
    cfg["data"], cfg["val"] = smoke["data"], smoke["val"]
    cfg["noise"] = dict(cfg["noise"], gaussian_fraction=0.25, clean_fraction=0.25)
    raw, rgb, feats = train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 3, 8)
    clean = train_demosaic.mosaic_rggb(rgb)
    assert torch.equal(raw[6:], clean[6:]) and bool((feats[6:] == 0).all())
    assert bool(((raw[:6] - clean[:6]).flatten(1).std(1) > 1e-4).all())
    assert bool((feats[:2, 0] == 0).all()) and bool((feats[2:6, 0] > 0).all())
    cfg["noise"]["clean_fraction"] = 0.9
    with pytest.raises(ValueError, match="clean_fraction"):
        train_demosaic.make_batch(train_demosaic.make_sampler(cfg), cfg, 3, 8)


def test_natural_pool_is_the_cameras_noise_free_output():
    """One simulator: the natural pool's image, un-white-balanced (times the item's white, von Kries) and mosaicked
    RGGB, is the noise-free raw of `Camera(scene)` for the item's camera and natural scene (camera_for), and a
    perfect white under the scene's main light is (1, 1, 1) after the white balance (the gains are 1 / white)."""
    from isettorch.data.camera_pairs import camera_for

    cfg = common.load_config(SMOKE)
    pool = train_demosaic.make_sampler(cfg)
    ds = pool.pairs
    assert ds.scene_config["generator"] == "natural" and ds.camera_config["f_number"] == [2.0]
    img = pool.render(3)
    camera, scene, kw = camera_for(3, pool.seed, ds.scene_config, ds.camera_config)
    g = torch.Generator().manual_seed(kw.pop("noise_seed"))
    out = camera(scene, return_intermediates=True, generator=g, **kw)
    raw = out.raw
    nf = (raw.noise_free - raw.black_level) / (raw.white_level - raw.black_level)
    white = ds.get_batch([3])["meta"]["white_camera_rgb"][0]  # the white's camera response, G = 1
    own_white = scene.illuminant_photons[0].double() @ camera.sensor.spectral_weights(out.optical_image).double()
    torch.testing.assert_close(white.double(), own_white / own_white[1], rtol=1e-5, atol=0)
    unbalanced = img * white.float()[:, None, None]
    torch.testing.assert_close(train_demosaic.mosaic_rggb(unbalanced[None]), nf.float(), rtol=1e-5, atol=1e-6)


def _bank_cfg(tmp_path, count=3):
    cfg = common.load_config(SMOKE)
    cfg["data"].update(bank=count, bank_dir=str(tmp_path / "banks"), bank_workers=1)
    return cfg


def test_scene_bank_holds_the_pools_scenes_and_resumes(tmp_path, monkeypatch):
    """The bank is the pool's scenes 0..N-1 in float16; a deleted chunk is rendered again, the others are read."""
    monkeypatch.setattr(demosaic_data, "BANK_CHUNK", 2)  # SceneBank reads it there
    cfg = _bank_cfg(tmp_path)
    bank = train_demosaic.make_sampler(cfg)
    assert isinstance(bank, train_demosaic.SceneBank) and bank.images.dtype == torch.float16
    pool = train_demosaic.ScenePool(cfg, bank.seed)
    for i in range(3):
        torch.testing.assert_close(bank.images[i].float(), pool.render(i), rtol=2.0**-10, atol=1e-7)
    files = sorted(bank.folder.glob("scenes_*.pt"))
    assert [f.name for f in files] == ["scenes_0000000_0000002.pt", "scenes_0000002_0000003.pt"]
    kept = files[0].stat().st_mtime_ns
    files[1].unlink()
    again = train_demosaic.make_sampler(cfg)
    assert torch.equal(again.images, bank.images) and files[0].stat().st_mtime_ns == kept
    a = train_demosaic.make_batch(bank, cfg, 7, 4)
    b = train_demosaic.make_batch(again, cfg, 7, 4)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])


def test_rendering_the_bank_in_process_leaves_the_trainers_threads(tmp_path):
    """A bank rendered in the trainer's own process (one worker, or one chunk left) set torch to one thread for the
    rest of the run: slower, and not bitwise a resumed run (which loads the cached bank)."""
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        train_demosaic.make_sampler(_bank_cfg(tmp_path, 2))
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_scene_bank_is_keyed_on_the_scenes(tmp_path):
    """Another scene seed or generator config is another bank; batch, patch and domain keys share one."""
    cfg = _bank_cfg(tmp_path, 2)
    folder = train_demosaic.make_sampler(cfg).folder
    cfg["data"].update(batch=2, patch=16, domain="linear")
    assert train_demosaic.make_sampler(cfg).folder == folder
    cfg["data"]["colour_space"] = "linear_srgb"
    assert train_demosaic.make_sampler(cfg).folder != folder
    cfg["data"]["bank"] = 0.5
    with pytest.raises(ValueError, match="data.bank"):
        train_demosaic.make_sampler(cfg)


def test_linear_srgb_pool_renders_grey_as_neutral():
    """Colorimetric targets: grey materials under one light of any kind are neutral after the Bradford adaptation to
    D65 (R = G = B in linear sRGB up to the wavelength-dependent diffraction at edges); the camera-RGB pool needs its
    white balance for the same (its gains are the white's camera response)."""
    cfg = common.load_config(SMOKE)
    cfg["data"]["colour_space"] = "linear_srgb"
    cfg["data"]["natural"]["components"].update(palette={"grey_probability": 1.0},
                                                illuminant={"mixed_probability": 0.0})
    pool = train_demosaic.make_sampler(cfg)
    for i in range(4):
        img = pool.render(i).double()
        mean = img.mean((1, 2))
        torch.testing.assert_close(mean / mean[1], torch.ones(3, dtype=torch.float64), rtol=3e-3, atol=0)
    cfg["data"]["colour_space"] = "rec2020"
    with pytest.raises(ValueError, match="data.colour_space"):
        train_demosaic.make_sampler(cfg)


def test_joint_network_starts_as_the_noise_free_one():
    """init from a noise-free checkpoint: the two noise inputs get zero weights, so the outputs are equal for any
    noise level; a checkpoint of another width cannot start the network."""
    torch.manual_seed(0)
    free = train_demosaic.DemosaicNet(channels=8, depth=2)
    with torch.no_grad():
        free.head.weight.normal_(0, 0.1)
    ck = {"model": free.state_dict(), "net_config": free.config()}
    joint = train_demosaic.DemosaicNet(channels=8, depth=2, noise_inputs=2)
    joint.load_state_dict(train_demosaic.init_state(ck, joint))
    raw = torch.rand(2, 1, 16, 16)
    torch.testing.assert_close(joint(raw, torch.tensor([[0.3, 2.0], [1.0, 0.1]])), free(raw), rtol=0, atol=0)
    with pytest.raises(ValueError, match="cannot start"):
        train_demosaic.init_state(ck, train_demosaic.DemosaicNet(channels=16, depth=2, noise_inputs=2))
    # the guard holds no weights: a network with the guard in the loop starts from the checkpoint's weights as they
    # are, and its output is the guarded output of the checkpoint's network
    guard = {"rel": 0.1, "abs": 0.03, "highpass_sigma_px": 4.0}
    guarded = train_demosaic.DemosaicNet(channels=8, depth=2, guard=guard)
    guarded.load_state_dict(train_demosaic.init_state(ck, guarded))
    free.guard = guard
    torch.testing.assert_close(guarded(raw), free(raw), rtol=0, atol=0)
    # so do a correction scale and a blend: a network trained as a variant ships starts at that shipped function
    shipped = train_demosaic.DemosaicNet(channels=8, depth=2, guard=guard, correction_scale=0.5,
                                         blend={"method": "menon2007", "weight": 0.3})
    shipped.load_state_dict(train_demosaic.init_state(ck, shipped))
    free.correction_scale, free.blend = 0.5, {"method": "menon2007", "weight": 0.3}
    torch.testing.assert_close(shipped(raw), free(raw), rtol=0, atol=0)
    assert (shipped(raw) - guarded(raw)).abs().max() > 1e-3
    free.guard, free.correction_scale, free.blend = None, 1.0, None
    # another base: the same weights, now correcting that base (the tiny network moved to the unrefined Menon);
    # with another base and another width it cannot start
    on_menon = train_demosaic.DemosaicNet(channels=8, depth=2, base="menon2007_norefine")
    state = train_demosaic.init_state(ck, on_menon)
    assert all(torch.equal(state[k], v) for k, v in free.state_dict().items())
    with pytest.raises(ValueError, match="cannot start"):
        train_demosaic.init_state(ck, train_demosaic.DemosaicNet(channels=16, depth=2, base="menon2007_norefine"))


def test_deeper_residual_network_starts_as_the_shallower_one_and_its_new_blocks_learn():
    """init from a shallower residual checkpoint (Net2DeeperNet): the new blocks are identities, so the deeper
    network's output equals the checkpoint's exactly; one backward pass gives the new blocks' second convolutions a
    non-zero gradient (they can learn); a shallower or plain target cannot be started from it."""
    torch.manual_seed(0)
    small = train_demosaic.DemosaicNet(channels=8, depth=3, residual=True)
    with torch.no_grad():
        small.head.weight.normal_(0, 0.1)
        small.body[2].conv2.weight.normal_(0, 0.1)
    ck = {"model": small.state_dict(), "net_config": small.config()}
    deep = train_demosaic.DemosaicNet(channels=8, depth=7, residual=True)
    deep.load_state_dict(train_demosaic.init_state(ck, deep))
    raw = torch.rand(2, 1, 16, 16)
    out = deep(raw)
    torch.testing.assert_close(out, small(raw), rtol=0, atol=0)
    assert len(deep.body) == 2 + 3
    for i in (3, 4):
        assert float(deep.body[i].conv2.weight.abs().max()) == 0
        assert float(deep.body[i].conv1.weight.abs().max()) > 0
    (out - 0.5).square().mean().backward()
    assert all(float(deep.body[i].conv2.weight.grad.abs().max()) > 0 for i in (3, 4))
    for target in (train_demosaic.DemosaicNet(channels=8, depth=1, residual=True),
                   train_demosaic.DemosaicNet(channels=8, depth=7)):
        with pytest.raises(ValueError, match="cannot start"):
            train_demosaic.init_state(ck, target)


def test_bfloat16_autocast_runs_only_the_residual_in_bfloat16():
    """optim.precision bf16: an untrained network (zero head) is exactly the float32 Malvar-He-Cutler estimate under
    autocast, and a trained one differs from its float32 output only by the residual's bfloat16 rounding (relative
    step 2^-8 of the residual, not of the signal)."""
    torch.manual_seed(0)
    net = train_demosaic.DemosaicNet(channels=8, depth=2).to(memory_format=torch.channels_last)
    raw = torch.rand(2, 1, 16, 16)
    base = train_demosaic.demosaic_malvar2004(raw, "RGGB", boundary="mirror")
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = net(raw)
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, base, rtol=0, atol=0)
    net.requires_grad_(False)
    net.head.weight.normal_(0, 0.05)
    full = net(raw)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        half = net(raw)
    residual = (full - base).abs().max()
    assert 0 < float((half - full).abs().max()) < 0.03 * float(residual)


def test_adaptive_grad_clip_caps_outliers_at_a_multiple_of_the_running_norm():
    """optim.clip_grad_factor: steady gradients pass untouched; an outlier 100x larger is scaled to exactly
    factor x the running mean norm; the state resumes the same clipping; factor 0 never clips."""
    p = torch.nn.Parameter(torch.zeros(4))

    def step(clip, scale):
        p.grad = torch.full((4,), 0.5 * scale)  # norm = scale
        return clip([p])

    clip = train_demosaic.AdaptiveGradClip(2.0)
    for _ in range(20):
        assert step(clip, 1.0) == pytest.approx(1.0)
        assert float(p.grad.norm()) == pytest.approx(1.0)
    assert clip.ema == pytest.approx(1.0)
    resumed = train_demosaic.AdaptiveGradClip(2.0, clip.state())
    for c in (clip, resumed):
        assert step(c, 100.0) == pytest.approx(100.0)
        assert float(p.grad.norm()) == pytest.approx(2.0)
    assert clip.state() == resumed.state()
    off = train_demosaic.AdaptiveGradClip(0.0)
    step(off, 1.0)
    step(off, 100.0)
    assert float(p.grad.norm()) == pytest.approx(100.0)
    with pytest.raises(ValueError, match="clip_grad_factor"):
        train_demosaic.AdaptiveGradClip(-1.0)
    # a non-finite gradient stops the run (it made the EMA NaN, clipping off for good, and the weights NaN)
    for c in (clip, off):
        with pytest.raises(FloatingPointError, match="gradient's norm is nan"):
            step(c, float("nan"))
    assert clip.state() == resumed.state()


def test_a_scene_seed_that_draws_the_validation_scenes_is_refused(tmp_path):
    seed = 0  # (2 x VAL_SEED_OFFSET is 2000 x 1_000_003: scene_seed 2000 at rank 0; the audit's was seed 1, rank 1)
    colliding = (seed + 2 * train_demosaic.VAL_SEED_OFFSET) // 1_000_003  # its training pool is the validation's
    assert colliding * 1_000_003 == seed + 2 * train_demosaic.VAL_SEED_OFFSET
    with pytest.raises(SystemExit, match="data.scene_seed"):
        train_demosaic.main(["--config", str(SMOKE), "--out", str(tmp_path / "run"), "--no-progress", "--threads",
                             "1", "--set", f"seed={seed}", f"data.scene_seed={colliding}"])


def _teacher(tmp_path, noise_inputs=0):
    torch.manual_seed(3)
    net = train_demosaic.DemosaicNet(channels=8, depth=2, noise_inputs=noise_inputs)
    with torch.no_grad():  # a non-trivial head: the untrained network is MHC, which is transpose-equivariant
        for p in net.parameters():
            p.add_(0.05 * torch.randn_like(p))
    path = tmp_path / f"teacher{noise_inputs}.pt"
    torch.save({"model": net.state_dict(), "net_config": net.config()}, path)
    return net.eval(), path


def test_distill_target_is_the_teachers_self_ensemble_and_transpose_equivariant(tmp_path):
    net, path = _teacher(tmp_path)
    teacher, w, ens = train_demosaic.load_teacher({"distill": {"teacher": str(path), "weight": 0.25}}, "cpu")
    assert (w, ens) == (0.25, True)
    g = torch.Generator().manual_seed(0)
    rgb = torch.rand(2, 3, 12, 16, generator=g)
    raw = train_demosaic.mosaic_rggb(torch.rand(2, 3, 12, 16, generator=g))
    with torch.no_grad():  # the mean of the network on the mosaic and on its transpose, from the network itself
        two = 0.5 * (net(raw) + net(raw.transpose(-1, -2)).transpose(-1, -2))
    target = train_demosaic.distill_target(raw, rgb, None, teacher, w, ens)
    torch.testing.assert_close(target, 0.75 * rgb + 0.25 * two, rtol=0, atol=1e-6)
    one = train_demosaic.distill_target(raw, rgb, None, teacher, 1.0, False)
    with torch.no_grad():
        torch.testing.assert_close(one, net(raw), rtol=0, atol=1e-6)
        assert (one - two).abs().max() > 1e-3  # the teacher is not equivariant; its ensemble is, exactly:
    teacher8, _, ens8 = train_demosaic.load_teacher({"distill": {"teacher": str(path), "self_ensemble": "dihedral"}},
                                                    "cpu")
    assert ens8 == "dihedral"
    eight = train_demosaic.distill_target(raw, rgb, None, teacher8, 1.0, ens8)
    torch.testing.assert_close(eight, demosaic_learned(raw, model=net, self_ensemble="dihedral"), rtol=0,
                               atol=1e-6)
    assert (eight - two).abs().max() > 1e-4
    t_raw = raw.transpose(-1, -2)  # an RGGB mosaic transposes to an RGGB mosaic
    torch.testing.assert_close(train_demosaic.distill_target(t_raw, rgb.transpose(-1, -2), None, teacher, 1.0, True),
                               train_demosaic.distill_target(raw, rgb, None, teacher, 1.0, True).transpose(-1, -2),
                               rtol=0, atol=1e-6)


def test_distill_teacher_as_shipped(tmp_path):
    # distill.shipped: the teacher runs with a shipped variant's guard, scale and blend, so the target is that
    # configuration's output (the library's forward of the same network with those settings), not the bare network's
    net, path = _teacher(tmp_path)
    teacher, _, _ = train_demosaic.load_teacher({"distill": {"teacher": str(path), "self_ensemble": False,
                                                             "shipped": "noise_free"}}, "cpu")
    ref = learned.apply_shipped_settings(net, "noise_free")
    assert teacher.guard == learned.PRETRAINED_GUARDS["noise_free"] and teacher.blend == ref.blend is not None
    raw = train_demosaic.mosaic_rggb(torch.rand(1, 3, 24, 32, generator=torch.Generator().manual_seed(1)))
    target = train_demosaic.distill_target(raw, torch.zeros(1, 3, 24, 32), None, teacher, 1.0, False)
    with torch.no_grad():
        torch.testing.assert_close(target, ref(raw), rtol=0, atol=1e-6)
        bare = learned.load_checkpoint(path)[0]
        assert (target - bare(raw)).abs().max() > 1e-3
    with pytest.raises(ValueError, match="distill.shipped"):
        train_demosaic.load_teacher({"distill": {"teacher": str(path), "shipped": "huge"}}, "cpu")


def test_distill_config_errors_name_the_key(tmp_path):
    _, path = _teacher(tmp_path)
    for bad, key in (({"teacher": str(path), "weight": 0}, "distill.weight"),
                     ({"teacher": str(path), "self_ensemble": "yes"}, "distill.self_ensemble"),
                     ({"weight": 1.0}, "distill.teacher"), ({"teacher": str(path), "alpha": 1}, "distill: unknown")):
        with pytest.raises(ValueError, match=key):
            train_demosaic.load_teacher({"distill": bad}, "cpu")
    with pytest.raises(ValueError, match="noise inputs"):  # a noise-free teacher for a joint run
        train_demosaic.load_teacher({"distill": {"teacher": str(path)}, "noise": {"enabled": True}}, "cpu")


def test_distillation_run_trains_towards_the_teacher(tmp_path):
    """A student started from its teacher (one pass, weight 1) has a zero loss at its first step, to float rounding
    (the teacher runs the inference path, the same sums in another order): the targets are the teacher's outputs on
    the same mosaics, not the scenes. (One step: Adam scales even a rounding-sized gradient to a full step.)"""
    _, path = _teacher(tmp_path)
    args = ["--config", str(SMOKE), "--out", str(tmp_path / "run"), "--quiet", "--threads", "1", "--steps", "1",
            "--set", "val.every=1", f"init={path}", f"distill={{teacher: {path}, weight: 1.0, self_ensemble: false}}"]
    assert train_demosaic.main(args) == 0
    rows = list(csv.DictReader(open(tmp_path / "run" / "history.csv")))
    assert len(rows) == 1 and 0 <= float(rows[0]["train_loss"]) < 1e-12
    rec = json.loads((tmp_path / "run" / "record.json").read_text())
    assert rec["config"]["distill"]["teacher"] == str(path)
    # the same run towards the scenes has a loss
    args[-1] = f"distill={{teacher: {path}, weight: 0.5, self_ensemble: false}}"
    args[3] = str(tmp_path / "half")
    assert train_demosaic.main(args) == 0
    assert float(next(csv.DictReader(open(tmp_path / "half" / "history.csv")))["train_loss"]) > 1e-5
