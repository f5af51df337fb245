"""The shared progress-bar helper (isettorch._progress)."""

import io

import pytest

from isettorch._progress import add_quiet_argument, progress


def test_quiet_returns_the_iterable_and_a_silent_manual_bar():
    items = [1, 2, 3]
    assert progress(items, desc="x", quiet=True) is items
    bar = progress(total=5, quiet=True)
    bar.update(2)
    bar.set_postfix(loss=1.0)
    bar.close()
    assert bar.n == 2


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
