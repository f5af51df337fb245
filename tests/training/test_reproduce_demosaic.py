"""training/reproduce_demosaic.py: the shipped models' training chains are consistent (every step starts from, and
every teacher is, a checkpoint an earlier step writes), a broken chain is refused, and the interpolation screen
chooses and writes the network its rule says; training.heldout_screen.interpolate_checkpoints is exact."""

import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from isettorch.isp.learned import DemosaicNet  # noqa: E402
from training import heldout_screen, reproduce_demosaic  # noqa: E402

SHIPPED = ROOT / "isettorch" / "assets" / "demosaic_learned.pt"


def test_chains_are_consistent_and_end_where_the_selection_starts():
    nf = reproduce_demosaic.check_chain(reproduce_demosaic.CHAINS["noise_free"])
    outs = [c["out"] + "/best.pt" for c in nf]
    assert reproduce_demosaic.WISE["start"] in outs and outs[-1] == reproduce_demosaic.WISE["finetuned"]
    assert all(c["init"] == o for c, o in zip(nf[1:], outs[:-1]))  # a straight line of continuations
    joint = reproduce_demosaic.check_chain(reproduce_demosaic.CHAINS["joint_denoise"])
    # the joint model starts from the shipped noise-free network, the file the noise_free chain's export writes
    assert joint[-1]["noise"]["enabled"] and joint[0]["init"] == "isettorch/assets/demosaic_learned.pt"
    assert all(c["init"] == p["out"] + "/best.pt" for p, c in zip(joint[:-1], joint[1:]))


def test_broken_chain_is_refused(tmp_path):
    (tmp_path / "a.yaml").write_text("out: out/a\n")
    (tmp_path / "b.yaml").write_text("out: out/b\ninit: out/a/best.pt\ndistill: {teacher: out/x/best.pt}\n")
    (tmp_path / "c.yaml").write_text("out: out/c\ninit: out/z/best.pt\n")
    with pytest.raises(ValueError, match="'b' reads distill.teacher 'out/x/best.pt'"):
        reproduce_demosaic.check_chain(["a", "b"], tmp_path)
    with pytest.raises(ValueError, match="'c' reads init"):
        reproduce_demosaic.check_chain(["a", "c"], tmp_path)
    with pytest.raises(ValueError, match="does not exist"):
        reproduce_demosaic.check_chain(["a", "missing"], tmp_path)


def test_dry_run_lists_the_steps(capsys, monkeypatch):
    monkeypatch.chdir(reproduce_demosaic.ROOT)
    assert reproduce_demosaic.main(["noise_free", "--dry-run"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].endswith("configs/train/demosaic_noise_free.yaml --no-progress")
    assert sum("train_demosaic.py" in line for line in lines) == len(reproduce_demosaic.CHAINS["noise_free"])
    assert sum("make_heldout.py" in line for line in lines) == 5 and "export_demosaic.py" in lines[-1]
    with pytest.raises(SystemExit):
        reproduce_demosaic.main(["colour", "--dry-run"])
    # the family members: a first step from scratch (no init), the tiny one then distilled (twice, the second time
    # on the unrefined Menon base), exported as their variant
    for model, last in (("tiny", "tiny_norefine"), ("small", "small")):
        assert reproduce_demosaic.main([model, "--dry-run"]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert lines[0] == (f"python training/train_demosaic.py --config configs/train/demosaic_{model}.yaml "
                            f"--no-progress")
        assert lines[-1].startswith(f"python training/export_demosaic.py --run out/train_demosaic_{last} ")
        assert f"--variant {model}" in lines[-1] and len(lines) == len(reproduce_demosaic.CHAINS[model]) + 1
        assert "init" not in reproduce_demosaic.check_chain(reproduce_demosaic.CHAINS[model])[0]


def test_interpolate_checkpoints_exact():
    torch.manual_seed(0)
    a, b = (DemosaicNet(channels=8, depth=2) for _ in range(2))
    ca = {"model": a.state_dict(), "net_config": {"channels": 8, "depth": 2}, "optimizer": {}, "step": 3}
    cb = {"model": b.state_dict(), "net_config": {"channels": 8, "depth": 2}}
    for alpha, want in ((0.0, a.state_dict()), (1.0, b.state_dict())):
        got = heldout_screen.interpolate_checkpoints(alpha, ca, cb)["model"]
        for k, v in want.items():
            torch.testing.assert_close(got[k], v.float(), rtol=0, atol=0)
    half = heldout_screen.interpolate_checkpoints(0.5, ca, cb)
    k = "head.weight"
    torch.testing.assert_close(half["model"][k], (a.state_dict()[k] + b.state_dict()[k]) / 2)
    assert half["step"] == 3 and "optimizer" not in half  # the start's record, without its optimizer state
    with pytest.raises(ValueError, match="alpha"):
        heldout_screen.interpolate_checkpoints(1.5, ca, cb)
    cc = {"model": DemosaicNet(channels=8, depth=3).state_dict(), "net_config": {"channels": 8, "depth": 3}}
    with pytest.raises(ValueError, match="same architecture"):
        heldout_screen.interpolate_checkpoints(0.5, ca, cc)


def test_wise_select_ships_the_best_passing_alpha(tmp_path, tiny_heldout_sets, damaged_shipped):
    """Start = the shipped network with its output head damaged, fine-tune = the shipped network: the screen must
    pick an alpha > 0, write exactly that interpolation, and keep the start when the roles are swapped."""
    sets = tiny_heldout_sets
    good, bad = (torch.load(p, weights_only=True) for p in (SHIPPED, damaged_shipped))
    how, res = reproduce_demosaic.wise_select(sets, damaged_shipped, SHIPPED, tmp_path / "w")
    chosen = res["decision"]
    assert chosen != "incumbent" and res[chosen]["passes"] and f"W({float(chosen[1:])})" in how
    assert all(res[chosen]["score"] >= r["score"] for k, r in res.items() if k.startswith("a") and r["passes"])
    written = torch.load(tmp_path / "w" / "best.pt", weights_only=True)["model"]
    want = heldout_screen.interpolate_checkpoints(float(chosen[1:]), bad, good)["model"]
    assert all(torch.equal(written[k], want[k]) for k in want)
    how, res = reproduce_demosaic.wise_select(sets, SHIPPED, damaged_shipped, tmp_path / "w2")
    assert res["decision"] == "incumbent" and "passed no alpha" in how
    written = torch.load(tmp_path / "w2" / "best.pt", weights_only=True)["model"]
    assert all(torch.equal(written[k], good["model"][k]) for k in good["model"])


def test_runs_only_from_the_repository_root(tmp_path, monkeypatch, capsys):
    """The chain's training runs write out/... under the working directory, its selection screen reads under the
    repository: run elsewhere it trained for hours, then failed (or screened a stale out/). Refused at the start."""
    monkeypatch.chdir(tmp_path)
    for argv in (["tiny", "--dry-run"], ["noise_free"]):
        with pytest.raises(SystemExit) as err:
            reproduce_demosaic.main(argv)
        assert err.value.code == 2 and "repository root" in capsys.readouterr().err
