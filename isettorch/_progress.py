"""One progress-bar helper for every long job (``synth``, ``demo``, training, benchmarks, calibration).

Commands take ``--quiet`` (no bar, no chatter) and pass it here; the bar goes to stderr so stdout stays
machine-readable (``--json`` outputs), and it disables itself when stderr is not a terminal unless asked.

Example::

    from isettorch._progress import progress
    for item in progress(items, desc="render", quiet=args.quiet):
        ...
"""

from __future__ import annotations

import sys
from collections.abc import Iterable

__all__ = ["progress", "add_quiet_argument"]


def progress(iterable: Iterable | None = None, total: int | None = None, desc: str | None = None,
             quiet: bool = False, **kwargs):
    """A tqdm bar over ``iterable`` (or a manual bar with ``total`` when ``iterable`` is None).

    Args:
        iterable: what to iterate; ``len()`` gives the total when ``total`` is None.
        total: number of steps (for generators, or a manual bar updated with ``.update(n)``).
        desc: a short label shown before the bar.
        quiet: no bar at all (the iterable is returned as is; a manual bar becomes an object whose methods do
            nothing, except ``write``, which prints its line as ``tqdm.write`` does).
        kwargs: passed to ``tqdm`` (e.g. ``unit="pair"``, ``initial=step``, ``file=sys.stdout``).
    """
    if total is not None and (not isinstance(total, int) or total < 0):
        raise ValueError(f"total: expected a non-negative int or None, got {total!r}")
    if quiet:
        return iterable if iterable is not None else _NoBar()
    from tqdm.auto import tqdm

    kwargs.setdefault("file", sys.stderr)
    kwargs.setdefault("dynamic_ncols", True)
    # Not a terminal (CI logs, pipes): tqdm's default would still redraw; print only the final state.
    kwargs.setdefault("mininterval", 0.5 if _isatty(kwargs["file"]) else 30.0)
    return tqdm(iterable, total=total, desc=desc, **kwargs)


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


class _NoBar:
    """Stands in for a manual tqdm bar under ``quiet``: the same methods, doing nothing but ``write``."""

    n = 0

    def update(self, n: int = 1) -> None:
        self.n += n

    def set_postfix(self, *args, **kwargs) -> None:
        pass

    def set_postfix_str(self, *args, **kwargs) -> None:
        pass

    def refresh(self, *args, **kwargs) -> None:
        pass

    def set_description(self, *args, **kwargs) -> None:
        pass

    def write(self, s: str, file=None, end: str = "\n", nolock: bool = False) -> None:
        """Print ``s`` as ``tqdm.write`` does (a log line, not bar chatter: it is kept under ``quiet``)."""
        print(s, file=sys.stdout if file is None else file, end=end, flush=True)

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def add_quiet_argument(parser, *aliases: str) -> None:
    """Add the shared ``-q/--quiet`` flag (no progress bars) to an argparse (sub)parser; ``aliases`` are former
    names kept working (e.g. ``"--no-progress"``)."""
    help_ = "no progress bars" + (f" ({', '.join(aliases)}: the former name)" if aliases else "")
    parser.add_argument("-q", "--quiet", *aliases, dest="quiet", action="store_true", help=help_)
