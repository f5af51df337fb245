"""Behaviour of the benchmark scripts' options (benchmarks/, not part of the package): where their results go, what
they refuse, and how many times they measure. The measured workloads are replaced by stand-ins; timings are never
asserted."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCH))
import bench  # noqa: E402
import cuda_smoke  # noqa: E402
import demosaic_noise_speed as dns  # noqa: E402
import pipeline  # noqa: E402
import throughput  # noqa: E402


@pytest.fixture(autouse=True)
def _keep_threads():  # the scripts set torch's thread count
    n = torch.get_num_threads()
    yield
    torch.set_num_threads(n)


def test_pipeline_quick_refuses_the_committed_folder(monkeypatch, tmp_path, capsys):
    ran = []
    monkeypatch.setattr(bench, "run_benchmarks", lambda **kw: ran.append(kw) or {
        "rows": [], "seconds_total": 0.0, "machine": {"processor": "p", "cpu_count": 1, "torch_threads": 1}})
    monkeypatch.setattr(bench, "plot_pareto", lambda result, path: Path(path).write_bytes(b"") or path)
    monkeypatch.setattr(bench, "format_report", lambda result: "table")
    for argv in (["--quick"], ["--quick", "--out", str(BENCH)]):
        with pytest.raises(SystemExit) as err:
            pipeline.main(argv)
        assert err.value.code == 2
        msg = capsys.readouterr().err
        assert "--quick" in msg and "--out" in msg
    assert not ran  # refused before anything ran or was written
    assert pipeline.main(["--quick", "--out", str(tmp_path)]) == 0
    assert ran[0]["quick"] is True
    assert {p.name for p in tmp_path.iterdir()} == {"pipeline.json", "pipeline_table.md", "pareto.png"}


@pytest.mark.parametrize("extra", [[], ["--transport-ab", "2"]])
def test_throughput_loader_only_appends_markdown(monkeypatch, tmp_path, extra):
    calls = []

    def fake_rate(*args, shm_slots=True, **kw):
        calls.append(shm_slots)
        return (100.0 if shm_slots else 50.0), 1.0

    monkeypatch.setattr(throughput, "loader_rate", fake_rate)
    monkeypatch.setattr(throughput, "tune_allocator", lambda: False)
    md = tmp_path / "t.md"
    md.write_text("# kept\n")
    monkeypatch.setattr(sys, "argv", ["throughput.py", "--loader-only", "--count", "64", "--batch", "8",
                                      "--loader-batches", "8", "--markdown", str(md), *extra])
    throughput.main()
    text = md.read_text()
    assert text.startswith("# kept\n") and "\n### " in text  # appended under a dated heading
    table = [r for r in text.splitlines() if r.startswith("|")]
    assert table[1].startswith("|---")  # a header, then its rule, then the rows
    if extra:
        assert sorted(calls) == [False, False, True, True]
        assert "| slots / stock | 2.000, 2.000 | **2.000** |" in table
    else:
        assert len(table) == 3 and "README loader" in table[2]


def test_cuda_smoke_writes_each_line_as_its_check_ends(monkeypatch, tmp_path):
    out = tmp_path / "smoke.txt"
    seen = []

    def first(dev):
        pass

    def second(dev):
        seen.append(out.read_text())
        raise ValueError("broken")

    def third(dev):
        seen.append(out.read_text())

    monkeypatch.setattr(cuda_smoke, "CHECKS", [first, second, third])
    assert cuda_smoke.main(["--device", "cpu", "--out", str(out)]) == 0
    assert seen[0].startswith("PASS first") and seen[0].count("\n") == 1
    assert seen[1].splitlines()[1].startswith("FAIL second: ValueError: broken")
    assert [line.split()[:2] for line in out.read_text().splitlines()] == [
        ["PASS", "first"], ["FAIL", "second:"], ["PASS", "third"]]


def test_pairs_per_second_is_a_median_of_rounds_of_new_items(monkeypatch):
    import isettorch.data.camera_pairs as cp

    got = []

    class Fake:
        def __init__(self, n, **kw):
            self.n = n

        def __getitem__(self, i):
            assert 0 <= i < self.n
            got.append(i)

    monkeypatch.setattr(cp, "CameraPairDataset", Fake)
    rate, note = bench.pairs_per_second(4, log=lambda s: None)
    assert rate > 0 and "median of 3 rounds of 4 items" in note
    assert got == list(range(13))  # one warm-up item, then three rounds of new items


def test_demosaic_speed_rows_all_in_the_rounds_with_ratio_to_menon(monkeypatch, tmp_path):
    rng = np.random.default_rng(0)
    for name in ("a.png", "b.png"):
        Image.fromarray(rng.integers(0, 256, (20, 50, 3), dtype=np.uint8)).save(tmp_path / name)
    calls = []

    def fake_eval(folder, method, pattern, crop, **kw):
        calls.append((method, kw.get("noise_sigma"), kw.get("denoise")))
        ms = 2.0 if method == "menon2007" else 1.0
        return {"mean_cpsnr": 30.0, "images": [{"name": "a.png", "ms": ms}, {"name": "b.png", "ms": ms}]}

    monkeypatch.setattr(dns, "evaluate_demosaic", fake_eval)
    out = tmp_path / "speed.md"
    assert dns.main(["speed", "--kodak", str(tmp_path), "--mcmaster", str(tmp_path), "--rounds", "2", "-q",
                     "--out", str(out)]) == 0
    noisy = [c for c in calls if c[1] is not None]
    assert len(noisy) == 2 * 4 * 2  # rounds x noisy rows x sets
    assert len(calls) == 2 * (len(dns.SPEED_METHODS) + 1 + 4) * 2
    rows = {}
    for r in out.read_text().splitlines():
        if r.startswith("| ") and not r.startswith("| method"):
            cells = [c.strip() for c in r.strip("|").split("|")]
            rows.setdefault(cells[0], []).append(cells)
    assert len(rows["menon2007"]) == 2  # the noise-free and the noisy table
    for cells in rows["menon2007"]:
        assert cells[3] == cells[6] == "1.00"
    assert rows["bilinear"][0][3] == "0.50" and rows["nlmeans + menon2007"][0][6] == "1.00"
    assert "2 interleaved passes (every row)" in out.read_text()
