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

__all__ = ["progress", "add_quiet_argument", "abandon_bars"]


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
    kwargs.setdefault("file", sys.stderr)
    kwargs.setdefault("dynamic_ncols", True)
    tty = _isatty(kwargs["file"])
    kwargs.setdefault("mininterval", 0.5 if tty else 30.0)
    # Not a terminal (CI logs, pipes): no redraws, only the final state when the job ends well (so an error
    # message stays the only line of a failed command's stderr)
    return _bar_class(held=not tty)(iterable, total=total, desc=desc, **kwargs)


_BAR = _HELD_BAR = None


def _bar_class(held: bool = False):
    """tqdm (``tqdm.auto``'s) with ``_hold`` (draw nothing until a successful close) and ``_failed`` (an exception
    left its ``with`` block, or :func:`abandon_bars`: close without leaving the bar on screen)."""
    global _BAR, _HELD_BAR
    if _BAR is None:
        from tqdm.auto import tqdm

        class _Bar(tqdm):
            _hold = False
            _failed = False
            _final = False

            def display(self, *args, **kwargs):
                if self._hold and not self._final:
                    return None
                return super().display(*args, **kwargs)

            def close(self):
                if self._failed:
                    self.leave = False
                elif self._hold and not getattr(self, "disable", True):
                    self._final = True
                super().close()

            def __exit__(self, exc_type, exc_value, tb):
                if exc_type is not None:
                    self._failed = True
                return super().__exit__(exc_type, exc_value, tb)

        class _HeldBar(_Bar):
            _hold = True

        _BAR, _HELD_BAR = _Bar, _HeldBar
    return _HELD_BAR if held else _BAR


def abandon_bars() -> None:
    """Close every open bar without leaving it on screen (a terminal's bar line is cleared; elsewhere nothing was
    drawn): called before an error message, so the message is the only line on stderr."""
    if _BAR is None:
        return
    for bar in list(_BAR._instances):
        bar._failed, bar.leave = True, False
        bar.close()


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
