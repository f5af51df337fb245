"""`isettorch synth`: shards, checksums, manifest, resume after an abort, rank split, CLI."""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
import yaml

from isettorch.cli import main
from isettorch.data.camera_pairs import CameraPairDataset
from isettorch.data.writer import sha256_file, verify_dataset, write_dataset

CFG = {"seed": 5, "shard_size": 2, "scene": {"height": 16, "width": 16, "wavelengths_nm": [400.0, 700.0, 50.0]}}
COUNT = 7  # 4 shards: 2 + 2 + 2 + 1


class Abort(Exception):
    pass


def _checksums(out):
    return {p.name: sha256_file(p) for p in sorted(out.glob("shard-*.pt"))}


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("ref")
    manifest = write_dataset(CFG, out, COUNT, progress=False)
    return out, manifest


def test_uninterrupted_run_writes_checksummed_shards(reference):
    out, manifest = reference
    assert manifest["complete"] and manifest["num_files"] == 4 and len(manifest["shards"]) == 4
    assert json.loads((out / "manifest.json").read_text())["config_sha256"] == manifest["config_sha256"]
    assert verify_dataset(out) == []
    for rec in manifest["shards"]:
        assert sha256_file(out / rec["file"]) == rec["sha256"]
    # shard contents are the dataset's items, in order, loadable without pickle
    ds = CameraPairDataset(COUNT, seed=5, scene=CFG["scene"])
    last = torch.load(out / "shard-00003.pt", weights_only=True)
    assert last["raw"].shape == (1, 1, 16, 16) and last["meta"]["index"].tolist() == [6]
    assert torch.equal(last["raw"][0], ds[6]["raw"]) and torch.equal(last["camera_rgb"][0], ds[6]["camera_rgb"])
    assert not list(out.glob(".*tmp*"))


def test_resume_after_abort_gives_identical_files(reference, tmp_path):
    ref_out, _ = reference
    written = []

    def abort_after_two(f):
        written.append(f)
        if len(written) == 2:
            raise Abort

    with pytest.raises(Abort):
        write_dataset(CFG, tmp_path, COUNT, progress=False, on_shard_written=abort_after_two)
    assert len(list(tmp_path.glob("shard-*.pt"))) == 2
    # a shard half-written by the killed run (stale temp file) and a corrupted shard do not fool the resume
    (tmp_path / ".shard-00002.pt.tmp999").write_bytes(b"partial")
    first = sorted(tmp_path.glob("shard-*.pt"))[0]
    mtime = first.stat().st_mtime_ns
    resumed = []
    manifest = write_dataset(CFG, tmp_path, COUNT, progress=False, on_shard_written=resumed.append)
    assert resumed == [2, 3] and first.stat().st_mtime_ns == mtime  # finished shards were skipped
    assert manifest["complete"]
    assert _checksums(tmp_path) == _checksums(ref_out)
    # a damaged shard fails verification and is rebuilt identically on the next run
    (tmp_path / "shard-00001.pt").write_bytes(b"garbage")
    assert any("checksum" in p for p in verify_dataset(tmp_path))
    again = []
    write_dataset(CFG, tmp_path, COUNT, progress=False, on_shard_written=again.append)
    assert again == [1] and _checksums(tmp_path) == _checksums(ref_out)


def test_a_dataset_of_another_generator_version_is_never_resumed(tmp_path, monkeypatch):
    """A folder holding shards drawn by another generator version is refused (not mixed); its shards would not
    match anyway (the version enters the config hash)."""
    from isettorch.data import writer

    first = []
    manifest = write_dataset(CFG, tmp_path, 4, progress=False, on_shard_written=first.append)
    assert first == [0, 1] and manifest["generator_version"] == writer.GENERATOR_VERSION
    again = []
    write_dataset(CFG, tmp_path, 4, progress=False, on_shard_written=again.append)
    assert again == []  # same version: nothing to do
    old_hash = writer.config_hash(manifest["config"], 4)
    monkeypatch.setattr(writer, "GENERATOR_VERSION", writer.GENERATOR_VERSION + 1)
    assert writer.config_hash(manifest["config"], 4) != old_hash
    with pytest.raises(ValueError, match="generator version"):
        write_dataset(CFG, tmp_path, 4, progress=False)


def test_ranks_and_shards_split_the_files(reference, tmp_path, monkeypatch):
    ref_out, _ = reference
    seen = {}
    for shard in range(2):
        for rank in range(2):
            monkeypatch.setenv("RANK", str(rank))
            monkeypatch.setenv("WORLD_SIZE", "2")
            got = []
            write_dataset(CFG, tmp_path, COUNT, shard=shard, num_shards=2, progress=False,
                          on_shard_written=got.append)
            seen[(shard, rank)] = got
    files = sorted(f for v in seen.values() for f in v)
    assert files == [0, 1, 2, 3]  # each file written by exactly one (shard, rank)
    assert _checksums(tmp_path) == _checksums(ref_out)
    assert json.loads((tmp_path / "manifest.json").read_text())["complete"]


def test_a_dataset_the_disk_cannot_hold_stops_after_its_first_shard(tmp_path, monkeypatch):
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10**6, 10**6 - 100, 100))  # 100 bytes free
    with pytest.raises(OSError, match=r"out: the 3 shards left need about"):
        write_dataset(CFG, tmp_path, COUNT, progress=False)
    assert sorted(p.name for p in tmp_path.glob("*.pt")) == ["shard-00000.pt"]  # the first one is kept


def test_config_errors(tmp_path):
    with pytest.raises(ValueError, match="scene.colour"):
        write_dataset({"scene": {"colour": 1}}, tmp_path, 2, progress=False)
    write_dataset(CFG, tmp_path / "a", 2, progress=False)
    with pytest.raises(ValueError, match=r"another config, count or generator version \(the config\)"):
        write_dataset({**CFG, "seed": 6}, tmp_path / "a", 2, progress=False)
    with pytest.raises(ValueError, match=r"\(count 2 there, 3 here\); use a new folder"):  # (it named only a hash)
        write_dataset(CFG, tmp_path / "a", 3, progress=False)


def test_cli_in_process_and_subprocess(reference, tmp_path, capsys):
    ref_out, _ = reference
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(yaml.safe_dump(CFG))
    assert main(["synth", "--config", str(cfg), "--out", str(tmp_path / "a"), "--count", str(COUNT),
                 "--no-progress"]) == 0
    assert _checksums(tmp_path / "a") == _checksums(ref_out)
    assert main(["synth", "--out", str(tmp_path / "a"), "--count", str(COUNT), "--verify"]) == 0
    assert main(["synth", "--out", str(tmp_path / "a"), "--verify"]) == 0  # --count optional with --verify
    capsys.readouterr()
    assert main(["synth", "--out", str(tmp_path / "a"), "--count", "999", "--verify"]) == 1  # (it printed "ok")
    assert f"count: the dataset holds {COUNT} items, --count 999" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("scene:\n  heigth: 16\n")
    assert main(["synth", "--config", str(bad), "--out", str(tmp_path / "b"), "--count", "2"]) == 2
    assert "scene.heigth" in capsys.readouterr().err
    # a separate process produces the same bytes
    r = subprocess.run([sys.executable, "-m", "isettorch.cli", "synth", "--config", str(cfg), "--out",
                        str(tmp_path / "c"), "--count", str(COUNT), "--no-progress"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert _checksums(tmp_path / "c") == _checksums(ref_out)


def test_targets_option_writes_only_those(tmp_path):
    """`targets` in the synth config: shards hold raw, meta and the asked targets, equal to the full dataset's."""
    cfg = {**CFG, "targets": ["camera_rgb"]}
    write_dataset(cfg, tmp_path, 2, progress=False)
    shard = torch.load(tmp_path / "shard-00000.pt", weights_only=True)
    assert set(shard) == {"raw", "camera_rgb", "meta"}
    full = CameraPairDataset(2, seed=5, scene=CFG["scene"]).get_batch([0, 1])
    # 3 instead of 6 spectral projections: the same values up to GEMM rounding (which may flip a rare noise draw)
    assert float((shard["raw"] != full["raw"]).double().mean()) < 0.01
    assert float((shard["camera_rgb"] - full["camera_rgb"]).abs().max()) < 1e-6
    with pytest.raises(ValueError, match="targets"):
        write_dataset({**CFG, "targets": ["rgb"]}, tmp_path / "bad", 2, progress=False)


def test_shard_dataset_reads_back_the_items(reference, tmp_path):
    """ShardDataset(out)[i] is CameraPairDataset(...)[i] of the same config, bitwise; it loads through a DataLoader;
    incomplete, corrupt or truncated datasets raise errors naming the problem."""
    from isettorch.data.camera_pairs import collate_pairs
    from isettorch.data.writer import ShardDataset

    out, _ = reference
    shards = ShardDataset(out, verify=True, cache_shards=1)
    ds = CameraPairDataset(COUNT, seed=5, scene=CFG["scene"])
    assert len(shards) == COUNT
    for i in (0, 3, 6, -1):
        a, b = shards[i], ds[i % COUNT]
        assert set(a) == set(b)
        for k in ("raw", "noise_free_raw", "camera_rgb", "srgb"):
            assert torch.equal(a[k], b[k]), k
        for k, v in b["meta"].items():
            assert torch.equal(a["meta"][k], v), k
    with pytest.raises(IndexError):
        shards[COUNT]
    with pytest.raises(TypeError, match="index"):
        shards[1.5]
    assert torch.equal(shards[np.int64(5)]["raw"], ds[5]["raw"]) and torch.equal(shards[torch.tensor(5)]["raw"],
                                                                              ds[5]["raw"])
    batches = list(torch.utils.data.DataLoader(shards, batch_size=3, collate_fn=collate_pairs))
    assert [b["raw"].shape[0] for b in batches] == [3, 3, 1]
    assert batches[1]["meta"]["index"].tolist() == [3, 4, 5]
    assert torch.equal(shards.get_batch([4, 1])["xyz"], ds.get_batch([4, 1])["xyz"])

    half = tmp_path / "half"
    write_dataset(CFG, half, COUNT, shard=0, num_shards=2, progress=False)
    with pytest.raises(ValueError, match="incomplete"):
        ShardDataset(half)
    with pytest.raises(ValueError, match="manifest"):
        ShardDataset(tmp_path / "nothing")
    broken = tmp_path / "broken"
    write_dataset(CFG, broken, COUNT, progress=False)
    data = (broken / "shard-00001.pt").read_bytes()
    (broken / "shard-00001.pt").write_bytes(data[: len(data) // 2])  # truncated
    with pytest.raises(ValueError, match="checksum"):
        ShardDataset(broken, verify=True)
    with pytest.raises(ValueError, match="shard-00001.pt"):
        ShardDataset(broken)[2]
    # a complete manifest missing a shard's record (a KeyError at the item), a cache size that is not an integer
    manifest = json.loads((broken / "manifest.json").read_text())
    manifest["shards"] = manifest["shards"][:1]
    (broken / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match=r"lists no shard for files \[1"):
        ShardDataset(broken)
    with pytest.raises(ValueError, match="cache_shards: expected a positive integer, got 'x'"):
        ShardDataset(out, cache_shards="x")
    for bad in ({**manifest, "shard_size": 0}, {**manifest, "shard_size": -2}, [manifest]):
        (broken / "manifest.json").write_text(json.dumps(bad))
        with pytest.raises(ValueError, match="has a malformed manifest.json"):
            ShardDataset(broken)


def test_synth_quiet_flag(tmp_path, capsys):
    # --quiet (and its former name --no-progress) turns the progress bar off; the summary line stays.
    from isettorch.cli import main

    for flag in ("--quiet", "--no-progress"):
        out = tmp_path / flag.strip("-")
        cfg = tmp_path / "tiny.yaml"
        cfg.write_text("shard_size: 2\nscene: {height: 16, width: 16}\ncamera: {margin_px: 2}\n")
        assert main(["synth", "--config", str(cfg), "--out", str(out), "--count", "2", flag]) == 0
        captured = capsys.readouterr()
        assert "1/1 shards" in captured.out and "shard/s" not in captured.err and "it/s" not in captured.err


def test_an_edited_shard_is_refused_and_another_configs_shards_are_never_rewritten(reference, tmp_path):
    """A shard edited after it was written (one byte, same size) or another shard copied over it was served as
    training data: ShardDataset checks each shard's sha256 against the manifest when it reads it. A folder whose
    manifest is unreadable (or missing, after an aborted run) but whose shards were made with another config had
    every shard rewritten: the sidecars' config hashes refuse it."""
    import shutil

    from isettorch.data.writer import ShardDataset

    out, _ = reference
    edited = tmp_path / "edited"
    shutil.copytree(out, edited)
    data = bytearray((edited / "shard-00001.pt").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (edited / "shard-00001.pt").write_bytes(bytes(data))
    ds = ShardDataset(edited)
    assert torch.equal(ds[0]["raw"], ShardDataset(out)[0]["raw"])  # the other shards still read
    with pytest.raises(ValueError, match=r"shard-00001.pt: the shard's sha256 differs from manifest.json's"):
        ds[2]
    swapped = tmp_path / "swapped"
    shutil.copytree(out, swapped)
    shutil.copy(swapped / "shard-00000.pt", swapped / "shard-00001.pt")
    with pytest.raises(ValueError, match="sha256 differs"):
        ShardDataset(swapped)[2]
    other = tmp_path / "other"
    shutil.copytree(out, other)
    (other / "manifest.json").write_text("{garbage")
    before = _checksums(other)
    with pytest.raises(ValueError, match="holds shards made with another config"):
        write_dataset({**CFG, "seed": 6}, other, COUNT, progress=False)
    (other / "manifest.json").unlink()
    with pytest.raises(ValueError, match="holds shards made with another config"):
        write_dataset({**CFG, "seed": 6}, other, COUNT, progress=False)
    assert _checksums(other) == before


def test_verify_names_a_malformed_or_short_manifest(reference, tmp_path, capsys):
    """A manifest that is a list, a record without 'file', shards that are not records, a null count gave
    tracebacks (exit 1); a manifest that says complete but lists fewer shards than the count needs verified 'ok'
    (ShardDataset then refused the folder). Now: one line naming --out, exit 2; the short one is a problem (exit 1)."""
    import shutil

    out, manifest = reference
    bad = {"list": [], "no_file": {**manifest, "shards": [{k: v for k, v in r.items() if k != "file"}
                                                          for r in manifest["shards"]]},
           "strings": {**manifest, "shards": ["a", "b"]}, "int": {**manifest, "shards": 5},
           "null_count": {**manifest, "count": None}}
    for name, m in bad.items():
        d = tmp_path / name
        shutil.copytree(out, d)
        (d / "manifest.json").write_text(json.dumps(m))
        assert verify_dataset(d)[0].startswith("manifest.json: malformed"), name
        capsys.readouterr()
        assert main(["synth", "--out", str(d), "--verify"]) == 2, name
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"isettorch synth: --out: {d}/manifest.json: malformed"), err
    d = tmp_path / "short"
    shutil.copytree(out, d)
    (d / "manifest.json").write_text(json.dumps({**manifest, "shards": manifest["shards"][:1]}))
    assert verify_dataset(d) == ["manifest.json: complete, but lists no shard for files [1, 2, 3] (of 4)"]
    assert main(["synth", "--out", str(d), "--verify"]) == 1


def test_shard_items_are_copies_and_the_manifest_is_checked(reference, tmp_path):
    """An in-place edit of an item changed the cached shard (the next read of it returned the edit); a manifest of
    another format version was read as this one; a count edited from 7 to 8 gave 8 items, the last an IndexError."""
    import shutil

    from isettorch.data.writer import ShardDataset

    out, manifest = reference
    ds = ShardDataset(out)
    first = ds[1]["raw"].clone()
    ds[1]["raw"].mul_(0).add_(7)
    ds[1]["meta"]["index"].add_(100)
    assert torch.equal(ds[1]["raw"], first) and int(ds[1]["meta"]["index"]) == 1
    assert torch.equal(ds[1]["raw"], CameraPairDataset(COUNT, seed=CFG["seed"], scene=CFG["scene"])[1]["raw"])
    for name, edit, message in (("version", {"format_version": 99}, "format_version 99, this isettorch reads 1"),
                                ("count", {"count": COUNT + 1}, "config_sha256 is not the hash of its config and "
                                                                "count")):
        d = tmp_path / name
        shutil.copytree(out, d)
        (d / "manifest.json").write_text(json.dumps({**manifest, **edit}))
        with pytest.raises(ValueError, match=f"malformed manifest.json .*{message}"):
            ShardDataset(d)
        assert verify_dataset(d)[0].startswith("manifest.json: malformed") and message in verify_dataset(d)[0]


def test_an_unfinished_run_is_named_and_the_manifest_is_written_under_a_lock(tmp_path, monkeypatch, capsys):
    """A run stopped before its end leaves shards but no manifest: it was called 'not a dataset written by
    isettorch synth'. Two ranks finishing together wrote their sidecar scans in either order (a finished dataset
    left marked 8 of 12): the scan and the write hold an exclusive lock."""
    fcntl = pytest.importorskip("fcntl")
    from isettorch.data import writer
    from isettorch.data.writer import ShardDataset

    def stop(f):
        raise Abort

    with pytest.raises(Abort):
        write_dataset(CFG, tmp_path / "cut", COUNT, progress=False, on_shard_written=stop)
    with pytest.raises(ValueError, match=r"holds 1 shard\(s\) of an unfinished isettorch synth run: run the same"):
        ShardDataset(tmp_path / "cut")
    assert main(["synth", "--out", str(tmp_path / "cut"), "--verify"]) == 2
    assert "has no manifest.json; it holds 1 shard(s) of an unfinished isettorch synth run" in capsys.readouterr().err
    held = []
    write = writer._write_json

    def probe(path, data):  # another process's attempt to take the lock while this one writes the manifest
        if path.name == "manifest.json":
            with open(path.parent / ".manifest.lock", "a") as other:
                with pytest.raises(BlockingIOError):
                    fcntl.flock(other, fcntl.LOCK_EX | fcntl.LOCK_NB)
            held.append(True)
        write(path, data)

    monkeypatch.setattr(writer, "_write_json", probe)
    assert write_dataset(CFG, tmp_path / "cut", COUNT, progress=False)["complete"] and held == [True]


def test_a_rank_from_the_environment_says_so(tmp_path, monkeypatch):
    monkeypatch.setenv("RANK", "1")
    monkeypatch.delenv("WORLD_SIZE", raising=False)
    with pytest.raises(ValueError, match=r"rank: expected 0 <= rank < world_size \(1\), got 1 \(from the environment: "
                                         r"RANK='1', WORLD_SIZE=None; torchrun sets both\)"):
        write_dataset(CFG, tmp_path / "r", COUNT, progress=False)


def test_a_manifest_from_before_the_generator_version_and_a_file_system_without_locks(reference, tmp_path,
                                                                                     monkeypatch):
    """A manifest written before the generator version was recorded (hashed without it) was refused as edited; a file
    system without flock (Lustre without -o flock: ENOSYS) stopped every run before its manifest."""
    import errno
    import hashlib
    import shutil

    fcntl = pytest.importorskip("fcntl")
    from isettorch.data.writer import FORMAT_VERSION, ShardDataset

    out, manifest = reference
    old = tmp_path / "old"
    shutil.copytree(out, old)
    legacy = {k: v for k, v in manifest.items() if k != "generator_version"}
    blob = json.dumps({"config": manifest["config"], "count": COUNT, "format": FORMAT_VERSION}, sort_keys=True)
    legacy["config_sha256"] = hashlib.sha256(blob.encode()).hexdigest()
    (old / "manifest.json").write_text(json.dumps(legacy))
    assert len(ShardDataset(old)) == COUNT and verify_dataset(old) == []

    def no_locks(fd, op):
        raise OSError(errno.ENOSYS, "Function not implemented")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    assert write_dataset(CFG, tmp_path / "nolock", COUNT, progress=False)["complete"]
