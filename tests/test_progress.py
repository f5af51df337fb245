"""The shared progress-bar helper (isettorch._progress)."""

import io

import pytest

from isettorch._progress import add_quiet_argument, progress


def test_quiet_returns_the_iterable_and_a_silent_manual_bar(capsys):
    items = [1, 2, 3]
    assert progress(items, desc="x", quiet=True) is items
    bar = progress(total=5, quiet=True)
    bar.update(2)
    bar.set_postfix(loss=1.0)
    bar.set_postfix_str("stage")  # every manual-bar method the library calls (bench --quiet called this one)
    bar.set_description("x")
    bar.refresh()
    bar.close()
    assert bar.n == 2
    assert capsys.readouterr() == ("", "")
    # write() is tqdm.write: a log line (training rows), printed even without a bar
    buf = io.StringIO()
    bar.write("step=2 loss=0.1", file=buf)
    bar.write("to stdout")
    assert buf.getvalue() == "step=2 loss=0.1\n" and capsys.readouterr().out == "to stdout\n"


def test_bar_goes_to_the_given_stream_and_counts():
    buf = io.StringIO()
    assert list(progress(range(4), desc="render", file=buf, mininterval=0)) == [0, 1, 2, 3]
    assert "render" in buf.getvalue() and "4/4" in buf.getvalue()
    with progress(total=3, desc="manual", file=buf) as bar:
        bar.update(3)
    assert "3/3" in buf.getvalue()
    with pytest.raises(ValueError, match="total"):
        progress(total=-1)


def test_quiet_argument():
    import argparse

    p = argparse.ArgumentParser()
    add_quiet_argument(p)
    assert p.parse_args(["-q"]).quiet and p.parse_args(["--quiet"]).quiet and not p.parse_args([]).quiet
    old = argparse.ArgumentParser()
    add_quiet_argument(old, "--no-progress")  # a former flag name kept working
    assert old.parse_args(["--no-progress"]).quiet and old.parse_args(["-q"]).quiet
    assert not old.parse_args([]).quiet
