"""training/train_color.py: Bradford adaptation vs colour-science, rendering invariants, MCC fit, smoke run."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from training import train_color  # noqa: E402

colour = pytest.importorskip("colour")


def test_bradford_matches_colour_science():
    rng = np.random.default_rng(0)
    xyz = rng.random((5, 3))
    white = np.array([1.0985, 1.0, 0.3558])  # illuminant A, Y = 1
    ref = colour.adaptation.chromatic_adaptation_VonKries(xyz, white, train_color.D65_XYZ.numpy(),
                                                           transform="Bradford")
    ours = train_color.bradford_to_d65(torch.from_numpy(xyz)[None], torch.from_numpy(white)[None])[0]
    np.testing.assert_allclose(ours.numpy(), ref, rtol=1e-10, atol=1e-12)


def test_delta_e_2000_matches_colour_science():
    rng = np.random.default_rng(1)
    a = rng.random((50, 3)) * [100, 120, 120] - [0, 60, 60]
    b = a + rng.standard_normal((50, 3)) * 3
    ref = colour.delta_E(a, b, method="CIE 2000")
    ours = train_color.delta_e_2000(torch.from_numpy(a), torch.from_numpy(b))
    np.testing.assert_allclose(ours.numpy(), ref, rtol=1e-9, atol=1e-9)


def test_render_white_balance_and_adapted_white():
    data = train_color.ColorData("nikon_5100")
    g = torch.Generator().manual_seed(0)
    for _ in range(3):
        spd = data.illuminant(g)
        ones = torch.ones(2, train_color.WAVELENGTHS.numel(), dtype=torch.float64)
        rgb, white, xyz = data.render(ones, spd)
        # a perfect white reflector: camera RGB (1, 1, 1) after von Kries, XYZ adapted exactly to D65 (Y = 1)
        torch.testing.assert_close(rgb, torch.ones_like(rgb))
        torch.testing.assert_close(xyz, train_color.D65_XYZ.expand(2, 3), rtol=1e-10, atol=1e-12)
        assert torch.isclose(white.sum(), torch.tensor(1.0, dtype=torch.float64))


def test_lstsq_matrix_recovers_a_linear_map():
    g = torch.Generator().manual_seed(2)
    m = torch.randn(2, 3, 3, generator=g, dtype=torch.float64)
    rgb = torch.rand(2, 24, 3, generator=g, dtype=torch.float64)
    torch.testing.assert_close(train_color.lstsq_matrix(rgb, rgb @ m.transpose(-1, -2)), m)


def test_untrained_chart_model_is_the_mcc_matrix():
    g = torch.Generator().manual_seed(3)
    rgb, chart_rgb = torch.rand(2, 10, 3, generator=g), torch.rand(2, 24, 3, generator=g)
    chart_xyz = torch.rand(2, 24, 3, generator=g)
    white = torch.full((2, 3), 1 / 3)
    net = train_color.ColorNet(torch.eye(3), "mlp", 8, "chart")
    expected = rgb @ train_color.lstsq_matrix(chart_rgb, chart_xyz).transpose(-1, -2)
    torch.testing.assert_close(net(rgb, white, chart_rgb, chart_xyz), expected)
    with pytest.raises(ValueError, match="chart_rgb"):
        net(rgb, white)


def test_color_smoke_run(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("seed: 0\nmodels: [matrix]\nhidden: 8\ndata: {scenes_per_batch: 4, reflectances_per_scene: 8}\n"
                   "optim: {lr: 1.0e-3, steps: 2}\nval: {scenes: 4, reflectances_per_scene: 8, every: 1}\n")
    assert train_color.main(["--config", str(cfg), "--out", str(tmp_path / "o"), "--threads", "1", "--quiet"]) == 0
    # --quiet: no bar on stderr; the JSON rows (steps 0, 1, 2) still on stdout
    captured = capsys.readouterr()
    assert "step/s" not in captured.err and "2/2" not in captured.err
    assert [json.loads(line)["step"] for line in captured.out.splitlines()] == [0, 1, 2]
    rec = json.loads((tmp_path / "o" / "record.json").read_text())
    assert rec["final"]["step"] == 2 and np.isfinite(rec["final"]["matrix"])
    ck = torch.load(tmp_path / "o" / "color_models.pt", weights_only=True)
    assert "matrix" in ck["models"]


def test_a_misspelt_key_is_named_and_the_shipped_config_passes(tmp_path):
    """A typo (data.filter, optim.step) ran with its default without a word; the shipped color.yaml's keys pass."""
    from pathlib import Path

    from training import common

    cfg = tmp_path / "c.yaml"
    cfg.write_text("seed: 0\ndata: {filter: sony}\noptim: {lr: 1.0e-3, steps: 2}\n")
    with pytest.raises(ValueError, match=r"config.data.filter: unknown key; expected one of \['filters', "):
        train_color.main(["--config", str(cfg), "--out", str(tmp_path / "o")])
    shipped = common.load_config(Path(__file__).resolve().parents[2] / "configs" / "train" / "color.yaml")
    common.check_keys(shipped, train_color.COLOR_TOP_KEYS, train_color.COLOR_SECTION_KEYS)


def test_one_step_trains_at_the_full_rate_and_bad_steps_are_named(tmp_path, capsys):
    """The cosine schedule was lr (1 + cos(pi step / steps)) / 2 for step 1..steps: the last step's rate was 0, so a
    1-step run left the zero-initialised last layer of the conditioning at 0. Steps 0 wrote untrained models with
    exit 0, a missing one was a KeyError, val.every 0 a ZeroDivisionError."""
    cfg = tmp_path / "c.yaml"
    body = ("seed: 0\nmodels: [matrix]\nhidden: 8\ndata: {scenes_per_batch: 4, reflectances_per_scene: 8}\n"
            "optim: {lr: 1.0e-2%s}\nval: {scenes: 4, reflectances_per_scene: 8, every: %d}\n")
    cfg.write_text(body % (", steps: 1", 1))
    assert train_color.main(["--config", str(cfg), "--out", str(tmp_path / "o"), "--threads", "1", "--quiet"]) == 0
    last = [v for k, v in torch.load(tmp_path / "o" / "color_models.pt", weights_only=True)["models"]["matrix"].items()
            if k.startswith("cond.") and k.endswith(".weight")][-1]
    assert float(last.abs().sum()) > 0
    for steps, every, message in ((", steps: 0", 1, r"optim.steps: expected an integer >= 1, got 0"),
                                  ("", 1, r"optim.steps: expected an integer >= 1, got None"),
                                  (", steps: 2", 0, r"val.every: expected an integer >= 1, got 0")):
        cfg.write_text(body % (steps, every))
        with pytest.raises(ValueError, match=message):
            train_color.main(["--config", str(cfg), "--out", str(tmp_path / "p"), "--quiet"])


def test_bad_sizes_rates_and_model_lists_are_named(tmp_path):
    """An audit of training/: scenes_per_batch 0 failed in torch.stack, 0 held-out reflectances scored NaN with exit
    0, hidden 0 ran and -3 failed unnamed, lr -1 was Adam's error, models [] wrote an empty color_models.pt and
    models 'matrix' (a string) was read letter by letter. Each is named before anything runs."""
    cfg = tmp_path / "c.yaml"
    base = ("seed: 0\nmodels: [matrix]\nhidden: 8\ndata: {scenes_per_batch: 4, reflectances_per_scene: 8}\n"
            "optim: {lr: 1.0e-2, steps: 1}\nval: {scenes: 4, reflectances_per_scene: 8, every: 1}\n")
    for override, message in (("data.scenes_per_batch=0", r"config.data.scenes_per_batch: expected an integer >= 1"),
                              ("val.scenes=0", r"config.val.scenes: expected an integer >= 1"),
                              ("val.reflectances_per_scene=0", r"config.val.reflectances_per_scene: expected"),
                              ("hidden=0", r"config.hidden: expected an integer >= 1, got 0"),
                              ("hidden=-3", r"config.hidden: expected an integer >= 1, got -3"),
                              ("optim.lr=-1", r"config.optim.lr: expected a positive number, got -1"),
                              ("models=[]", r"config.models: expected a non-empty list of 'matrix' and 'mlp'"),
                              ("models=matrix", r"config.models: expected a non-empty list .* got 'matrix'")):
        cfg.write_text(base)
        with pytest.raises(ValueError, match=rf"^{message}"):
            train_color.main(["--config", str(cfg), "--out", str(tmp_path / "o"), "--quiet", "--set", override])
    assert not (tmp_path / "o" / "color_models.pt").exists()


def test_lstsq_matrix_gives_the_same_bits_on_every_call():
    """The default CPU driver (gelsy) differed between identical calls by up to 3e-7 under 2 threads, so two runs
    of one seed drifted apart (weights 3e-8, losses in the 5th digit); the QR driver is deterministic."""
    g = torch.Generator().manual_seed(0)
    rgb, xyz = torch.rand(32, 64, 3, generator=g), torch.rand(32, 64, 3, generator=g)
    first = train_color.lstsq_matrix(rgb, xyz)
    assert all(torch.equal(train_color.lstsq_matrix(rgb, xyz), first) for _ in range(30))
    ref = torch.linalg.lstsq(rgb.double(), xyz.double(), driver="gelsd").solution.transpose(-1, -2)
    torch.testing.assert_close(first.double(), ref, rtol=0, atol=1e-5)
