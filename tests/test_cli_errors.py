"""One error convention for the whole CLI: every subcommand, given bad input, prints ONE line on stderr,
``isettorch <command>: <message naming the argument>``, and exits 2, without a traceback.

The commands are discovered from the parser, so a new command is covered as soon as it exists: it gets the
generic case (a nonexistent path for each positional argument) or, if it has no positional argument, fails
here until it gets a row in ``CASES``.
"""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from isettorch import cli
from isettorch.cli import build_parser, main, subcommands

COMMANDS = sorted(subcommands(build_parser()))
MISSING = "{tmp}/no_such_input"

# command -> [(arguments after the command, text the error line must contain: the argument's name)]. Placeholders:
# {tmp} a fresh folder, {images} a folder with one 8-bit RGB PNG, {broken} a folder with a .png that is not an
# image, {garbage} a file that is neither TorchScript nor weights.
CASES: dict[str, list[tuple[list[str], str]]] = {
    "bench": [(["--threads", "0"], "--threads")],  # validated by benchmarks/bench.py in a child process
    "calibrate": [([MISSING], "DIR"), (["{images}/a.png"], "a.png: cannot read the frame")],
    "demo": [(["--size", "8", "--out", "{tmp}/out"], "--size"),
             (["--config", "{tmp}/no_such.yaml", "--out", "{tmp}/out"], "--config")],
    "demosaic-eval": [([MISSING], "DIR"), (["{broken}"], "DIR: cannot read b.png"),
                      (["{images}", "--noise-sigma", "-0.1"], "--noise-sigma"),
                      (["{images}", "--noise-shot", "nan"], "--noise-shot"),
                      (["{images}", "--model", "{tmp}/missing.pt"], "--model"),
                      (["{images}", "--model", "{garbage}"], "--model"),
                      (["{images}", "--method", "no_such_method"], "--method"),
                      (["{images}", "--crop", "-1"], "--crop")],
    "design-eval": [([MISSING, "{images}"], "DESIGN"), (["learned", "{images}"], "--crop"),
                    (["learned", "{images}", "--crop", "2", "--lux", "3"], "--lux"),
                    (["{garbage}", "{images}"], "DESIGN")],
    "lens-report": [([MISSING, "--json"], "no_such_input"),
                    (["cooke_triplet", "--fields", "a,b", "--json"], "--fields")],
    "parity": [([MISSING + ".npz"], "no_such_input.npz"), (["{tmp}/x.npz", "--repeat", "-1"], "--repeat")],
    "process": [([MISSING, "--camera", "default", "--model", "{garbage}"], "RAW"),
                (["{images}/a.png", "--camera", "{tmp}/no_such.yaml", "--model", "{garbage}"], "--camera"),
                (["{images}/a.png", "--camera", "default", "--model", "{tmp}/missing.pt"], "--model"),
                (["{images}/a.png", "--camera", "default", "--model", "{garbage}"], "--model"),
                (["{images}/a.png", "--camera", "default", "--model", "{garbage}", "--analog-gain", "0"],
                 "--analog-gain"),
                (["{images}/a.png", "--camera", "default", "--model", "{garbage}", "--exposure-s", "-1"],
                 "--exposure-s")],
    "synth": [(["--config", "{tmp}/no_such.yaml", "--out", "{tmp}/out", "--count", "2"], "--config"),
              (["--out", "{tmp}/out", "--count", "0"], "--count"),
              (["--out", MISSING, "--count", "1", "--verify"], "--out")],
    "view": [(["--port", "70000", "--no-browser"], "--port"), (["--size", "4", "--no-browser"], "--size")],
}


def _positionals(command: str) -> list:
    parser = subcommands(build_parser())[command]
    return [a for a in parser._actions if not a.option_strings and a.dest != "help"]


def _cases(command: str) -> list[tuple[list[str], str]]:
    if command in CASES:
        return CASES[command]
    if _positionals(command):  # generic: a nonexistent path for every positional argument (DESIGN DIR: two)
        return [([MISSING] * len(_positionals(command)), "no_such_input")]
    return []


PARAMS = [pytest.param(c, i, id=f"{c}-{i}") for c in COMMANDS for i in range(max(1, len(_cases(c))))]


@pytest.fixture
def places(tmp_path) -> dict:
    images, broken = tmp_path / "images", tmp_path / "broken"
    images.mkdir()
    broken.mkdir()
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)).save(images / "a.png")
    (broken / "b.png").write_bytes(b"not a png")
    (tmp_path / "garbage.pt").write_bytes(b"neither TorchScript nor weights")
    return {"tmp": str(tmp_path), "images": str(images), "broken": str(broken), "garbage": str(tmp_path / "garbage.pt")}


@pytest.mark.parametrize(("command", "case"), PARAMS)
def test_bad_input_is_one_line_and_exit_code_2(command, case, places, capfd, monkeypatch):
    monkeypatch.delenv("ISETTORCH_DEBUG", raising=False)
    cases = _cases(command)
    if not cases:
        pytest.fail(f"isettorch {command} has no positional argument for the generic bad-input case: add its "
                    f"bad input to CASES in {__file__}")
    args, named = cases[case]
    args = [a.format(**places) for a in args]
    code = main([command, *args])
    out, err = capfd.readouterr()  # capfd: bench's child process writes to file descriptor 2
    lines = err.splitlines()
    assert code == 2, (command, args, out, err)
    assert "Traceback" not in out + err
    assert len(lines) == 1, f"expected one line on stderr, got {lines!r}"
    assert lines[0].startswith(f"isettorch {command}: "), lines[0]
    assert named.format(**places) in lines[0], f"the error does not name {named!r}: {lines[0]!r}"


def test_cases_name_existing_commands():
    assert set(CASES) <= set(COMMANDS), f"CASES rows for commands that do not exist: {set(CASES) - set(COMMANDS)}"


def test_messages_use_the_command_line_spelling():
    """A library message that starts with a parameter's name is shown with the option or metavar."""
    parser = subcommands(build_parser())["demosaic-eval"]
    assert cli._spelled("noise_shot: expected >= 0", parser) == "--noise-shot: expected >= 0"
    assert cli._spelled("model_class: no class\n  given", parser) == "--model-class: no class given"
    assert cli._spelled("folder: missing", parser) == "DIR: missing"
    assert cli._spelled("weights: not a file", parser) == "weights: not a file"  # not a parameter: unchanged


def test_traceback_flag_and_debug_variable_reraise(places, monkeypatch, capsys):
    monkeypatch.delenv("ISETTORCH_DEBUG", raising=False)
    missing = MISSING.format(**places)
    with pytest.raises(FileNotFoundError, match="DIR: no such folder"):
        main(["--traceback", "demosaic-eval", missing])
    monkeypatch.setenv("ISETTORCH_DEBUG", "1")
    with pytest.raises(FileNotFoundError, match="DIR: no such folder"):
        main(["demosaic-eval", missing])
    assert capsys.readouterr().err == ""


def test_a_bug_keeps_its_traceback(monkeypatch):
    """Only input errors (ValueError, OSError) become one line: anything else is a bug and propagates."""
    from isettorch.commands import demosaic_eval

    def broken(args):
        raise KeyError("a bug")

    monkeypatch.setattr(demosaic_eval, "run", broken)
    with pytest.raises(KeyError, match="a bug"):
        main(["demosaic-eval", "anything"])
