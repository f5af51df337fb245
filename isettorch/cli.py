"""The ``isettorch`` command. Subcommands live in ``isettorch/commands/<name>.py``; each module defines
``register(subparsers)`` which adds its parser and sets ``func`` (a callable taking the parsed
args and returning an exit code). Modules are discovered automatically.

Errors: bad input to a subcommand is one line on stderr, ``isettorch <command>: <message>``, and exit code 2
(argparse's own errors too: one line, :class:`OneLineParser`; a progress bar left open by the error is cleared
first, :func:`isettorch._progress.abandon_bars`; ``--seed`` and ``--threads`` are checked by one rule for every
command, :func:`check_common`). A command signals bad input by raising ``ValueError`` or ``OSError``
(``FileNotFoundError``, ``PermissionError``, ...) with a message that names the argument; a message that starts
with the name of one of the command's parameters (``noise_sigma: ...``, as the library's functions name theirs)
is shown with the command line's spelling (``--noise-sigma: ...``). A broken pipe on stdout (``| head``) is not an
input error: the command stops quietly with exit code 141 (128 + SIGPIPE). Any other exception is a bug and keeps its
traceback; ``isettorch --traceback COMMAND ...`` or ``ISETTORCH_DEBUG=1`` re-raises input errors too."""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

from . import __version__, commands
from ._progress import abandon_bars


class OneLineParser(argparse.ArgumentParser):
    """argparse's own errors (a bad number, a missing option, an unknown command) as one line,
    ``isettorch SUB: error: <message> (see isettorch SUB --help)``, exit code 2; ``--help`` is unchanged. Subparsers
    are made with the parser's class, so every subcommand's parser is one too."""

    def error(self, message: str):
        message = " ".join(line.strip() for line in message.splitlines() if line.strip())
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="isettorch", description="Physically based camera simulation in PyTorch.")
    parser.add_argument("--version", action="version", version=f"isettorch {__version__}")
    parser.add_argument("--traceback", action="store_true",
                        help="show the Python traceback of an input error (as ISETTORCH_DEBUG=1 does)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        module.register(sub)
    return parser


#: The exception types that mean "bad input" (a missing file, a value out of range): one line and exit code 2.
INPUT_ERRORS = (ValueError, OSError)


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The subcommands' parsers of :func:`build_parser`'s parser, by name."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _spelled(message: str, parser: argparse.ArgumentParser | None) -> str:
    """``message`` on one line; a leading ``<dest>:`` of one of the command's parameters becomes its option string
    (``noise_sigma:`` -> ``--noise-sigma:``) or its metavar (a positional ``folder`` -> ``DIR:``)."""
    message = " ".join(line.strip() for line in message.splitlines() if line.strip())
    head, sep, rest = message.partition(":")
    if parser is None or not sep:
        return message
    for action in parser._actions:
        if action.dest == head and action.dest != "help":
            name = max(action.option_strings, key=len) if action.option_strings else action.metavar or head
            return f"{name}:{rest}"
    return message


def _silence_stdout() -> None:
    """Point stdout at /dev/null so Python's flush at exit does not fail again on the closed pipe (the idiom of the
    Python documentation, signal module, "Note on SIGPIPE")."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (AttributeError, OSError, ValueError):  # stdout without a file descriptor (e.g. captured in tests)
        pass


def max_threads() -> int:
    """The most CPU threads a command accepts: 4 per core, at least 64. More only adds contention (each thread also
    costs a stack and an OpenMP team slot), and a typo such as ``--threads 100000`` would exhaust the machine."""
    return max(64, 4 * (os.cpu_count() or 1))


def check_common(args) -> None:
    """The options several subcommands share, by one rule, before a command runs (so before it makes any folder):
    ``--seed`` an integer in ``[0, 2**64)`` (:func:`isettorch.data.config.check_seed`), ``--threads`` in
    ``[1, max_threads()]``, ``--workers`` (processes) in ``[0, max_threads()]`` (``--workers 100000`` started
    processes until the machine stalled)."""
    if getattr(args, "seed", None) is not None:
        from .data.config import check_seed

        check_seed(args.seed)
    threads = getattr(args, "threads", None)
    if threads is not None and not 1 <= threads <= max_threads():
        raise ValueError(f"threads: expected a number of CPU threads in [1, {max_threads()}] (4 per core, at least "
                         f"64), got {threads}")
    workers = getattr(args, "workers", None)
    if workers is not None and not 0 <= workers <= max_threads():
        raise ValueError(f"workers: expected a number of worker processes in [0, {max_threads()}] (4 per core, at "
                         f"least 64; 0: the main process), got {workers}")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        check_common(args)
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return code
    except BrokenPipeError:  # stdout closed by the reader (`| head`): not an input error; stop quietly
        _silence_stdout()
        return 141  # 128 + SIGPIPE, what a shell reports for a command killed by a broken pipe
    except INPUT_ERRORS as err:
        if args.traceback or os.environ.get("ISETTORCH_DEBUG", "") not in ("", "0"):
            raise
        abandon_bars()  # a bar left open by the error: cleared (or never drawn), so the message is the one line
        message = _spelled(str(err) or type(err).__name__, subcommands(parser).get(args.command))
        print(f"isettorch {args.command}: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
