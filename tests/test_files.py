"""isettorch._files: atomic writes (one implementation for shards, checkpoints and command outputs)."""

import os

import pytest
import torch

from isettorch._files import Outputs, torch_save_atomic, write_atomic


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "a.json"
    target.write_text("old")

    def fail(tmp):
        tmp.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomic(target, fail, durable=True)
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]
    write_atomic(target, lambda tmp: tmp.write_text("new"), durable=True)
    assert target.read_text() == "new" and sorted(p.name for p in tmp_path.iterdir()) == ["a.json"]


def test_durable_outputs_flush_each_file_before_the_move(tmp_path, monkeypatch):
    synced = []
    real = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(fd) or real(fd))
    with Outputs(tmp_path, durable=True) as outputs:
        outputs.temporary(tmp_path / "x.bin").write_bytes(b"1")
        outputs.temporary(tmp_path / "y.bin").write_bytes(b"2")
    assert len(synced) == 2 and (tmp_path / "y.bin").read_bytes() == b"2"
    synced.clear()
    with Outputs(tmp_path) as outputs:  # (command outputs: not flushed)
        outputs.temporary(tmp_path / "z.bin").write_bytes(b"3")
    assert synced == []


def test_torch_saves_do_not_depend_on_the_temporary_name(tmp_path, monkeypatch):
    """torch.save(obj, path) names the archive's folder after the file: the temporary name holds the process id, so
    shards written by two processes had other bytes (and checksums)."""
    obj = {"raw": torch.arange(6.0).reshape(2, 3)}
    torch_save_atomic(obj, tmp_path / "a.pt")
    monkeypatch.setattr(os, "getpid", lambda: 4242)
    torch_save_atomic(obj, tmp_path / "b.pt")
    assert (tmp_path / "a.pt").read_bytes() == (tmp_path / "b.pt").read_bytes()
    assert torch.equal(torch.load(tmp_path / "b.pt", weights_only=True)["raw"], obj["raw"])
