"""training/export_demosaic.py: the exported weights are the checkpoint's, and the model card's benchmark scores
(noise-free and with demosaic-eval's Gaussian noise) are those of isettorch.isp.evaluation on the same folder."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from isettorch.io.images import write_image  # noqa: E402
from isettorch.isp.evaluation import evaluate_demosaic  # noqa: E402
from isettorch.isp.learned import DemosaicNet, load_checkpoint  # noqa: E402
from training import export_demosaic, train_demosaic  # noqa: E402


def test_export_joint_model_card(tmp_path, monkeypatch):
    torch.manual_seed(0)
    net = DemosaicNet(channels=8, depth=2, noise_inputs=2)
    torch.nn.init.normal_(net.head.weight, std=0.02)
    opt = torch.optim.Adam(net.parameters())
    cfg = {"data": {"source": "natural"}, "noise": {"enabled": True}, "init": "out/noise_free/best.pt"}
    run = tmp_path / "run"
    run.mkdir()
    train_demosaic.save_checkpoint(run / "best.pt", net, opt, 7, cfg, 30.0, [{"step": 7, "val_cpsnr": 30.0}], 1.0)
    # a benchmark folder of two smooth 8-bit images under ISETTORCH_DATA
    data = tmp_path / "data" / "kodak24"
    data.mkdir(parents=True)
    yy, xx = np.mgrid[0:48, 0:64] / 64.0
    for i in range(2):
        img = np.stack([np.sin(3 * xx + i), np.cos(2 * yy), xx * yy], -1) * 0.4 + 0.5
        write_image(data / f"{i}.png", torch.from_numpy(img).permute(2, 0, 1), encoding="linear", bits=8)
    monkeypatch.setenv("ISETTORCH_DATA", str(tmp_path / "data"))
    out = tmp_path / "assets"
    assert export_demosaic.main(["--run", str(run), "--out", str(out), "--name", "jt", "--crops", "10",
                                 "--noise-sigmas", "0.02"]) == 0
    exported, _ = load_checkpoint(out / "jt.pt")
    for k, v in net.state_dict().items():
        torch.testing.assert_close(exported.state_dict()[k], v, rtol=0, atol=0)
    card = json.loads((out / "jt.json").read_text())
    scores = card["benchmarks_cpsnr_db"]["kodak24"]
    from isettorch.isp.learned import PRETRAINED_GUARDS

    # the file holds the guard it was scored under, so a --model load of it is the network its card scores (it
    # loaded bare)
    assert exported.guard == dict(PRETRAINED_GUARDS["joint_denoise"])
    clean = evaluate_demosaic(data, "learned", "RGGB", 10, model=exported)["mean_cpsnr"]
    noisy = evaluate_demosaic(data, "learned", "RGGB", 10, model=exported, noise_sigma=0.02, seed=0)["mean_cpsnr"]
    assert scores["crop10"] == pytest.approx(clean, abs=1e-3)
    assert scores["sigma0.02_crop10"] == pytest.approx(noisy, abs=1e-3)
    assert noisy < clean - 3  # std 0.02 noise (34 dB PSNR alone) costs far more than 3 dB on smooth images
    text = (out / "jt.md").read_text()
    assert "| kodak24 | " in text
    assert 'load_pretrained("joint_denoise")' in text.splitlines()[0]  # the card names the variant it documents
    assert "initialised from: `out/noise_free/best.pt`" in text
    assert '"highpass_sigma_px": 16.0' in text  # the card states the guard


def test_export_records_given_command_and_selection(tmp_path):
    """--command / --selected-by (a checkpoint not made by train_demosaic.py, e.g. a weight interpolation) replace the
    run record's command and the default selection text in the JSON and the card."""
    net = DemosaicNet(channels=8, depth=2)
    run = tmp_path / "run"
    run.mkdir()
    train_demosaic.save_checkpoint(run / "best.pt", net, torch.optim.Adam(net.parameters()), 3,
                                   {"data": {"source": "natural"}}, 30.0, [], 1.0)
    (run / "record.json").write_text(json.dumps({"command": "train_demosaic.py --config a.yaml"}))
    out = tmp_path / "assets"
    assert export_demosaic.main(["--run", str(run), "--out", str(out), "--no-bench"]) == 0
    card = json.loads((out / "demosaic_learned.json").read_text())
    assert card["command"] == "python training/train_demosaic.py --config a.yaml"
    assert card["checkpoint"]["selected_by"] == "synthetic validation CPSNR"
    assert export_demosaic.main(["--run", str(run), "--out", str(out), "--no-bench", "--command", "python w.py",
                                 "--selected-by", "a held-out screen"]) == 0
    card = json.loads((out / "demosaic_learned.json").read_text())
    assert card["command"] == "python w.py" and card["checkpoint"]["selected_by"] == "a held-out screen"
    text = (out / "demosaic_learned.md").read_text()
    assert "- command: `python w.py`" in text and "best by a held-out screen" in text
    # the exported file and its card hold what the variant ships with around the weights: guard, correction scale
    # and classical blend (a --model load of it ran the bare network, which the card does not score)
    from isettorch.isp import learned

    exported, _ = load_checkpoint(out / "demosaic_learned.pt")
    assert exported.guard == learned.PRETRAINED_GUARDS["noise_free"]
    assert exported.correction_scale == learned.PRETRAINED_CORRECTION_SCALES["noise_free"] != 1.0
    assert exported.blend == learned.PRETRAINED_BLENDS["noise_free"] is not None
    assert f"correction scale {learned.PRETRAINED_CORRECTION_SCALES['noise_free']:g}" in text


def test_export_refuses_a_variant_the_network_does_not_fit_and_a_missing_run(tmp_path, capsys):
    net = DemosaicNet(channels=8, depth=2)  # noise-free
    run = tmp_path / "run"
    run.mkdir()
    opt = torch.optim.Adam(net.parameters())
    train_demosaic.save_checkpoint(run / "best.pt", net, opt, 3, {"data": {}}, 30.0, [], 1.0)
    out = tmp_path / "assets"
    for argv, flag in ((["--run", str(run), "--variant", "joint_denoise"], "--variant"),  # (wrote a broken joint)
                       (["--run", str(tmp_path / "none")], "--run")):  # (a traceback)
        with pytest.raises(SystemExit) as exc:
            export_demosaic.main([*argv, "--out", str(out), "--no-bench"])
        assert exc.value.code == 2 and flag in capsys.readouterr().err
    assert not out.exists()


def test_shipped_checkpoints_record_the_step_and_validation_their_cards_give():
    """A shipped .pt carries the step and validation score of the weights it holds, as its .json card does: the
    accurate network is a weight interpolation of two runs, so it has no single step (it once carried one run's)."""
    import json

    from isettorch.isp.learned import PRETRAINED

    for variant, path in PRETRAINED.items():
        card = json.loads(Path(path).with_suffix(".json").read_text())
        ck = torch.load(path, map_location="cpu", weights_only=True)
        if card["checkpoint"]["which"] == "interpolation":
            assert ck["step"] is None and ck["best_val_cpsnr"] is None, variant
            steps = {k: v for k, v in card["checkpoint"].items() if k.endswith("_step")}
            assert len(steps) == 2 and all(ck["checkpoint"][k] == v for k, v in steps.items()), variant
        else:
            assert ck["step"] == card["checkpoint"]["step"], variant
            assert ck["best_val_cpsnr"] == card["validation_synthetic"]["val_cpsnr"], variant


def test_shipped_cards_name_the_start_the_reproduction_chain_uses():
    """A card whose run started from a then-shipped asset names the chain step that makes those weights, the start
    `training/reproduce_demosaic.py` uses (the asset itself is overwritten by the run it starts)."""
    from training import reproduce_demosaic

    variants = {"tiny": "demosaic_learned_tiny", "joint_denoise": "demosaic_learned_denoise",
                "small": "demosaic_learned_small"}
    for model, name in variants.items():
        card = json.loads((ROOT / "isettorch" / "assets" / f"{name}.json").read_text())
        last = reproduce_demosaic.load_config(reproduce_demosaic.CHAINS[model][-1])
        init = card["config"].get("init")
        if init and init.startswith("isettorch/assets/"):
            assert card["config"]["init_in_chain"].split(" ")[0] == last["init"], model
        else:
            assert init == last.get("init"), model


def test_an_interpolated_checkpoints_card_does_not_report_the_starts_validation(tmp_path):
    """A WiSE interpolation keeps its start's record: its card gave the start's step and validation rows as the
    interpolated network's. It now says it is interpolated and reports no validation of its own; a trained
    checkpoint's validation is labelled as the bare network's (the benchmarks score it as it ships)."""
    from training import heldout_screen

    nets = [DemosaicNet(channels=8, depth=2) for _ in range(2)]
    runs = []
    for i, net in enumerate(nets):
        run = tmp_path / f"run{i}"
        run.mkdir()
        train_demosaic.save_checkpoint(run / "best.pt", net, torch.optim.Adam(net.parameters()), 3 + i,
                                       {"data": {"source": "natural"}}, 30.0, [{"step": 3, "val_cpsnr": 33.6}], 33.6)
        runs.append(run)
    out = tmp_path / "assets"
    assert export_demosaic.main(["--run", str(runs[0]), "--out", str(out), "--no-bench"]) == 0
    card = json.loads((out / "demosaic_learned.json").read_text())
    assert card["validation_synthetic"] == {"val_cpsnr": 33.6} and "bare" in card["validation_of"]
    start, tuned = (torch.load(r / "best.pt", weights_only=True) for r in runs)
    torch.save(heldout_screen.interpolate_checkpoints(0.5, start, tuned), runs[0] / "best.pt")
    assert export_demosaic.main(["--run", str(runs[0]), "--out", str(out), "--no-bench"]) == 0
    card = json.loads((out / "demosaic_learned.json").read_text())
    assert card["validation_synthetic"] == {} and card["best_val_cpsnr"] is None
    assert card["checkpoint"]["interpolated"] == {"alpha": 0.5, "start_step": 3, "finetuned_step": 4}
    assert "weights interpolated" in (out / "demosaic_learned.md").read_text()
