"""One error convention for the whole CLI: every subcommand, given bad input, prints ONE line on stderr,
``isettorch <command>: <message naming the argument>``, and exits 2, without a traceback.

The commands are discovered from the parser, so a new command is covered as soon as it exists: it gets the
generic case (a nonexistent path for each positional argument) or, if it has no positional argument, fails
here until it gets a row in ``CASES``.
"""

from __future__ import annotations

import importlib.util
import os

import numpy as np
import pytest
from PIL import Image

from isettorch import cli
from isettorch.cli import build_parser, main, subcommands

COMMANDS = sorted(subcommands(build_parser()))
MISSING = "{tmp}/no_such_input"

# command -> [(arguments after the command, text the error line must contain: the argument's name)]. Placeholders:
# {tmp} a fresh folder, {images} a folder with one 8-bit RGB PNG (16 x 16), {broken} a folder with a .png that is not
# an image, {garbage} a file that is neither TorchScript nor weights, {strip} a folder with a 96 x 1 photograph,
# {mixed} a folder with a 16 x 16 and an 8 x 8 photograph, {keyed} an RGB PNG with a transparent colour key (tRNS),
# {pages} a two-page TIFF, {cam} a 12-bit RGGB camera config (white level 4095 DN), {darkcam} the same with a dark
# current, {badyaml} a camera config that is not YAML, {raw} a folder of 8 x 8 raw frames (frame.npy, frame.tif:
# one stem; shifted.npy: 12-bit data shifted left by 4 bits), {joint} the shipped joint denoise+demosaic network,
# {cap} a capture folder (capture.yaml, flat_1ms/ and dark_1ms/, whose frame_000.npy is truncated), {binyaml} a YAML
# file that is not UTF-8, {emptylist} a YAML file holding [] and {listyaml} one holding [1, 2].
# A device no torch build computes on: "fpga" (a device type torch parses but never implements).
PROC = ["--camera", "{cam}", "--model", "{joint}", "--out", "{tmp}/out", "--quiet"]  # (a frame's error ends its bar)
CASES: dict[str, list[tuple[list[str], str]]] = {
    "bench": [(["--threads", "0"], "--threads"),  # validated by benchmarks/bench.py in a child process
              (["--threads", "100000"], "--threads"), (["--repeats", "0"], "--repeats"),
              (["--repeats", "-1"], "--repeats"), (["--device", "fpga"], "--device: cannot compute on"),
              (["--sizes", "1000000"], "--sizes"), (["--plot", "{tmp}/no/dir/p.png"], "--plot"),
              (["--plot", "{garbage}/p.png"], "--plot"), (["--repeats", "abc"], "--repeats"),
              (["--bogus"], "--bogus"),
              (["--stable-size", "1"], "--stable-size: expected an integer in 16..4096"),  # (tracebacks)
              (["--stable-size", "100000000"], "--stable-size"), (["--knob-patch", "100000"], "--knob-patch"),
              # an empty value was read as the option not given: every section ran, exit 0
              (["--only", ""], "--only: expected a value"), (["--sizes", ""], "--sizes: expected a value"),
              (["--plot", ""], "--plot: expected a value")],
    "calibrate": [([MISSING], "DIR"), (["{images}/a.png"], "a.png: cannot read the frame"),
                  (["{cap}", "--report", "{cap}"], "--report: {cap} is the capture folder {cap}"),
                  (["{cap}", "--report", "{cap}/dark_1ms/r"], "--report: {cap}/dark_1ms/r is the capture folder"),
                  (["{cap}", "--out", "{tmp}/x", "--report", "{tmp}/x"], "--out: {tmp}/x is the --report folder"),
                  (["{tmp}", "--cfa", "RGGB"], "--cfa: applies to a single raw frame"),
                  (["{tmp}", "--black-level", "64"], "--black-level: applies to a single raw frame"),
                  (["{images}/a.png", "--out", "{tmp}/s.yaml"], "--out: a sensor config needs a capture folder"),
                  (["{images}/a.png", "--report", "{tmp}/r"], "--report: an EMVA 1288 report needs a capture folder"),
                  (["{cap}"], "frame_000.npy: cannot read the frame"),  # (no --quiet: the bar is not left behind)
                  (["{cap}", "-q", "--out", "{tmp}/s.yaml", "--report", "{garbage}/r"], "--report"),
                  (["{cap}", "-q", "--out", "{cap}/capture.yaml"], "--out"),
                  (["{cap}", "-q", "--out", "{cap}/dark_1ms/frame_001.npy"], "--out"),
                  (["{raw}/frame.npy", "--cfa", "nope"], "--cfa"),
                  (["{raw}/frame.npy", "--black-level", "abc"], "--black-level"),
                  (["{raw}/frame.npy"], "DIR: {raw}/frame.npy: only")],  # (named 'raw', the library's argument)
    "demo": [(["--size", "8", "--out", "{tmp}/out"], "--size"),
             (["--config", "{tmp}/no_such.yaml", "--out", "{tmp}/out"], "--config"),
             (["--out", "{garbage}"], "--out"), (["--out", "{garbage}/sub"], "--out"),
             (["--seed", "-1", "--out", "{tmp}/out"], "--seed"), (["--seed", "18446744073709551616"], "--seed"),
             (["--seed", "1.5"], "--seed"), (["--size", "1000000000", "--out", "{tmp}/out"], "--size"),
             (["--config", "{tmp}", "--out", "{tmp}/out"], "--config {tmp}: camera config")],  # (a stray 'path:')
    "demosaic-eval": [([MISSING], "DIR"), (["{broken}"], "DIR: cannot read b.png"),
                      (["{images}", "--noise-sigma", "-0.1"], "--noise-sigma"),
                      (["{images}", "--noise-shot", "nan"], "--noise-shot"),
                      (["{images}", "--model", "{tmp}/missing.pt"], "--model"),
                      (["{images}", "--model", "{garbage}"], "--model"),
                      (["{images}", "--method", "no_such_method"], "--method"),
                      (["{images}", "--crop", "-1"], "--crop"),
                      (["{images}", "--noise-sigma", "1e300"], "--noise-sigma: expected a standard deviation whose "
                                                               "square"),
                      (["{images}", "--noise-shot", "1e200"], "--noise-shot: expected a shot-noise gain whose square"),
                      (["{images}", "--device", "fpga"], "--device: cannot compute on 'fpga'"),
                      (["{images}", "--device", "foo"], "--device: 'foo' is not a torch device"),
                      (["{strip}"], "DIR: strip.png is 96 x 1 px"),
                      (["{mixed}", "--crop", "5"], "--crop: b.png is 8 x 8 px, too small for a 5-pixel border"),
                      (["{keyed}"], "DIR: keyed.png: expected an opaque image, 2 pixels are transparent"),
                      (["{pages}"], "DIR: pages.tif: expected a single image, got 2 pages"),
                      (["{images}", "--pattern", "XYZW"], "--pattern"),  # (no --quiet: checked before the bar)
                      (["{images}", "--threads", "100000"], "--threads"),
                      (["{images}", "--model", "{joint}", "--method", "menon2007"], "--method/--model"),
                      (["{images}", "--method", ""], "--method: expected one of"),
                      (["{images}", "--seed", "-1"], "--seed"), (["{images}", "--seed", "18446744073709551616"],
                                                                 "--seed"),
                      (["{images}", "--crop", "abc"], "--crop"),
                      # a custom model's errors (tracebacks before): not a class, kwargs the class refuses, weights
                      # that do not fit it
                      (["{images}", "--model", "{joint}", "--model-class", "os:path"],
                       "--model-class: 'os:path' is a module, not a class"),
                      (["{images}", "--model", "{joint}", "--model-class", "isettorch.isp.learned:DemosaicNet",
                        "--model-kwargs", '{{"bogus": 1}}'], "--model-kwargs: isettorch.isp.learned:DemosaicNet"),
                      (["{images}", "--model", "{joint}", "--model-class", "isettorch.isp.learned:DemosaicNet"],
                       "does not fit isettorch.isp.learned:DemosaicNet"),
                      (["{images}", "--method", "nearest", "--dihedral-ensemble"], "(--dihedral-ensemble)"),
                      # (both: the last one silently won)
                      (["{images}", "--self-ensemble", "--dihedral-ensemble"], "not allowed with")]
                     + ([] if importlib.util.find_spec("bm3d") else  # the user's package, when it is not installed
                        [(["{images}", "--noise-sigma", "0.1", "--denoise", "bm3d"], "--denoise: 'bm3d' needs")]),
    "design-eval": [([MISSING, "{images}"], "DESIGN"), (["learned", "{images}"], "--crop"),
                    (["learned", "{images}", "--crop", "2", "--lux", "3"], "--lux"),
                    # (repeated: both levels are checked; the last alone was, so 3 lux passed)
                    (["learned", "{images}", "--crop", "2", "--lux", "3", "--lux", "10"], "--lux"),
                    (["{garbage}", "{images}"], "DESIGN"),
                    (["learned", MISSING], "DIR: expected a folder"), (["learned", "{images}/a.png"], "DIR: expected"),
                    (["learned", "{tmp}"], "DIR: no .png"), (["learned", "{broken}"], "DIR: cannot read b.png"),
                    (["learned", "{images}", "--crop", "2", "--device", "foo"], "--device: 'foo' is not a torch"),
                    (["learned", "{images}", "--crop", "2", "--device", "fpga"], "--device: cannot compute on"),
                    (["learned", "{strip}", "--crop", "0"], "DIR: strip.png is 96 x 1 px"),
                    (["learned", "{mixed}", "--crop", "5"], "--crop: b.png is 8 x 8 px"),
                    (["learned", "{images}", "--crop", "2", "--lux", "100", "100"], "--lux: 100 is given twice"),
                    (["learned", "{images}", "--crop", "2", "--lux", "10", "10.0000001"],
                     "--lux: 10.0 and 10.0000001 are the same level to 6 significant digits"),
                    (["learned", "{images}", "--crop", "2", "--seed", "-1"], "--seed")],
    "lens-report": [([MISSING, "--json"], "no_such_input"),
                    (["cooke_triplet", "--fields", "a,b", "--json"], "--fields"),
                    (["cooke_triplet", "--out", "{garbage}"], "--out"), (["{binyaml}", "--json"], "lens"),
                    (["cooke_triplet", "--fields", "0,,1", "--json"], "--fields"),  # (the empty item was dropped)
                    (["cooke_triplet", "--wavelengths-nm", "5", "--json"],
                     "--wavelengths-nm: Cooke triplet f/5 40 deg, the medium after surface 1: glass")],
    "parity": [([MISSING + ".npz"], "no_such_input.npz"), (["{tmp}/x.npz", "--repeat", "-1"], "--repeat"),
               (["{tmp}"], "CASE {tmp}: '{tmp}' is a folder, expected a parity case .npz file"),  # ('no such case')
               (["{tmp}/x.npz", "--repeat", "1000000000"], "--repeat")],
    "process": [([MISSING, "--camera", "default", "--model", "{garbage}"], "RAW"),
                (["{images}/a.png", "--camera", "{tmp}/no_such.yaml", "--model", "{garbage}"], "--camera"),
                (["{images}/a.png", "--camera", "default", "--model", "{tmp}/missing.pt"], "--model"),
                (["{images}/a.png", "--camera", "default", "--model", "{garbage}"], "--model"),
                (["{images}/a.png", "--camera", "default", "--model", "{garbage}", "--analog-gain", "0"],
                 "--analog-gain"),
                (["{images}/a.png", "--camera", "default", "--model", "{garbage}", "--exposure-s", "-1"],
                 "--exposure-s"),
                (["{images}/a.png", "--camera", "default", "--model", "{garbage}", "--exposure-s", "inf"],
                 "--exposure-s: expected a finite exposure"),
                (["{raw}/frame.npy", *PROC, "--analog-gain", "1e308"], "--analog-gain: the gain 1e+308 makes"),
                (["{raw}/frame.npy", *PROC[2:], "--camera", "{darkcam}", "--exposure-s", "1e300"],
                 "--exposure-s: 1e+300 s of the sensor's dark current"),
                (["{raw}/frame.npy", "{raw}/frame.tif", *PROC], "RAW: {raw}/frame.npy and {raw}/frame.tif would both"),
                (["{raw}/shifted.npy", *PROC], "RAW: {raw}/shifted.npy: values up to 65520 DN exceed the camera's "
                                               "largest ADC code 4095 DN"),
                (["{raw}/frame.npy", *PROC[2:], "--camera", "{badyaml}"], "--camera: '{badyaml}' is not valid YAML"),
                (["{raw}/frame.npy", *PROC[:4], "--out", "{garbage}"],
                 "--out: expected a folder, {garbage} is a file"),
                (["{raw}/frame.npy", *PROC[:4], "--out", "{raw}", "-q"], "--out"),  # would overwrite the frame
                (["{raw}/frame.npy", "{broken}/b.png", *PROC[:4], "--out", "{tmp}/p"], "b.png"),  # no -q: one line
                (["{raw}/frame.npy", "--model", "{joint}"], "--camera"),  # argparse: one line
                (["{grey8}/g.png", *PROC], "RAW: {grey8}/g.png: 8-bit samples cannot hold the camera's 12-bit DN"),
                # an output file's name taken by a folder (found at the final move: the others were in place)
                (["{raw}/frame.npy", *PROC[:4], "--out", "{clash}", "-q"],
                 "--out: {clash}/frame.npy is a folder")],
    "synth": [(["--config", "{tmp}/no_such.yaml", "--out", "{tmp}/out", "--count", "2"], "--config"),
              (["--out", "{tmp}/out", "--count", "0"], "--count"),
              (["--out", "{tmp}/out"], "--count"),  # required unless --verify
              (["--out", MISSING, "--count", "1", "--verify"], "--out"),
              (["--out", "{images}", "--count", "1", "--verify"], "--out"),
              (["--config", "{emptylist}", "--out", "{tmp}/out", "--count", "1"], "--config"),
              (["--config", "{binyaml}", "--out", "{tmp}/out", "--count", "1"], "--config"),
              (["--out", "{garbage}", "--count", "1"], "--out"),
              (["--out", "{tmp}/out", "--count", "1", "--num-shards", "0"], "--num-shards"),
              (["--out", "{tmp}/out", "--count", "2", "--workers", "100000"], "--workers"),  # (it started them)
              (["--out", "{tmp}/out", "--count", "abc"], "--count"),
              (["--out", "{tmp}/out", "--count", "1000000000000000"], "--count"),  # (a silent hang)
              (["--config", "{unknownyaml}", "--out", "{tmp}/out", "--count", "1"],
               "--config: {unknownyaml}: foo: unknown config key")],
    "view": [(["--port", "70000", "--no-browser"], "--port"), (["--size", "4", "--no-browser"], "--size"),
             (["--size", "1000000", "--no-browser"], "--size"), (["--seed", "-1", "--no-browser"], "--seed"),
             (["--config", "{binyaml}", "--no-browser"], "--config"),
             (["--config", "{listyaml}", "--no-browser"], "--config"),
             (["--scene", "{tmp}/no_such.png", "--no-browser"], "--scene"),
             (["--address", "not a host", "--no-browser"], "--address")],
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
    folders = {name: tmp_path / name for name in ("strip", "mixed", "keyed", "pages", "raw", "grey8", "clash")}
    for folder in folders.values():
        folder.mkdir()
    (folders["clash"] / "frame.npy").mkdir()
    Image.fromarray(rng.integers(0, 256, (1, 96, 3), dtype=np.uint8)).save(folders["strip"] / "strip.png")
    Image.fromarray(rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)).save(folders["mixed"] / "a.png")
    Image.fromarray(rng.integers(0, 256, (8, 8, 3), dtype=np.uint8)).save(folders["mixed"] / "b.png")
    keyed = np.full((8, 8, 3), 100, np.uint8)
    keyed[0, :2] = (1, 2, 3)  # the two pixels of the transparent colour
    Image.fromarray(keyed).save(folders["keyed"] / "keyed.png", transparency=(1, 2, 3))
    page = Image.fromarray(rng.integers(0, 256, (8, 8, 3), dtype=np.uint8))
    page.save(folders["pages"] / "pages.tif", save_all=True, append_images=[page])
    frame = rng.integers(64, 4096, (8, 8)).astype(np.uint16)
    np.save(folders["raw"] / "frame.npy", frame)
    Image.fromarray(frame).save(folders["raw"] / "frame.tif")
    np.save(folders["raw"] / "shifted.npy", np.full((8, 8), 4095 << 4, np.uint16))
    Image.fromarray(np.full((8, 8), 200, np.uint8)).save(folders["grey8"] / "g.png")  # a display image
    sensor = ("sensor: {rows: 8, cols: 8, pixel_size_m: 3.45e-6, cfa: RGGB, adc_bits: 12, voltage_swing_v: 1.0, "
              "conversion_gain_v_per_e: 0.00048828125, black_level_dn: 64, read_noise_v: 0.00146484375")
    optics = "optics: {type: diffraction_limited, f_number: 2.8, focal_length_m: 0.004}\n"
    (tmp_path / "cam.yaml").write_text(optics + sensor + "}\n")
    (tmp_path / "darkcam.yaml").write_text(optics + sensor + ", dark_current_e_per_s: 50.0}\n")
    (tmp_path / "bad.yaml").write_text("sensor: [\n")
    (tmp_path / "bin.yaml").write_bytes(b"name: \x80\xff\n")
    (tmp_path / "emptylist.yaml").write_text("[]\n")
    (tmp_path / "list.yaml").write_text("[1, 2]\n")
    (tmp_path / "unknown.yaml").write_text("foo: 1\n")
    cap = tmp_path / "cap"
    (cap / "dark_1ms").mkdir(parents=True)
    (cap / "flat_1ms").mkdir()
    (cap / "capture.yaml").write_text("bit_depth: 12\npixel_size_m: 3.45e-6\n")
    for name in ("dark_1ms/frame_001.npy", "flat_1ms/frame_000.npy", "flat_1ms/frame_001.npy"):
        np.save(cap / name, frame)
    (cap / "dark_1ms" / "frame_000.npy").write_bytes((cap / "dark_1ms" / "frame_001.npy").read_bytes()[:40])
    from isettorch.isp.learned import PRETRAINED

    return {"tmp": str(tmp_path), "images": str(images), "broken": str(broken), "garbage": str(tmp_path / "garbage.pt"),
            **{name: str(folder) for name, folder in folders.items()}, "keyed": str(folders["keyed"]),
            "cam": str(tmp_path / "cam.yaml"), "darkcam": str(tmp_path / "darkcam.yaml"),
            "badyaml": str(tmp_path / "bad.yaml"), "joint": str(PRETRAINED["joint_denoise"]), "cap": str(cap),
            "binyaml": str(tmp_path / "bin.yaml"), "emptylist": str(tmp_path / "emptylist.yaml"),
            "listyaml": str(tmp_path / "list.yaml"), "unknownyaml": str(tmp_path / "unknown.yaml"),
            "pid": str(os.getpid())}  # (the commands run in this process: their temporary files' names)


def _main(argv: list[str]) -> int:
    """``main``'s exit code, argparse's own errors (SystemExit) included."""
    try:
        return main(argv)
    except SystemExit as stop:
        return stop.code


# Bad input leaves nothing behind: (arguments, paths that must not exist afterwards, files that must be unchanged).
LEFTOVERS = [
    (["process", "{raw}/frame.npy", "{broken}/b.png", *PROC[:4], "--out", "{tmp}/p"], ["{tmp}/p"], []),
    (["process", "{raw}/frame.npy", "{broken}/b.png", *PROC], ["{tmp}/out"], []),
    (["process", "{raw}/frame.npy", *PROC[:4], "--out", "{raw}", "-q"], [], ["{raw}/frame.npy"]),
    (["calibrate", "{cap}", "-q", "--out", "{tmp}/s.yaml", "--report", "{garbage}/r"], ["{tmp}/s.yaml"], []),
    (["calibrate", "{cap}", "-q", "--out", "{cap}/capture.yaml"], [], ["{cap}/capture.yaml"]),
    (["process", "{raw}/frame.npy", *PROC[:4], "--out", "{clash}", "-q"], ["{clash}/.frame.partial-{pid}.npy"],
     []),  # (a temporary file was left beside the folder that took the output's name)
    (["demo", "--seed", "-1", "--out", "{tmp}/o"], ["{tmp}/o"], []),
    (["demo", "--seed", "18446744073709551616", "--out", "{tmp}/o"], ["{tmp}/o"], []),
    (["demo", "--size", "1000000000", "--out", "{tmp}/o"], ["{tmp}/o"], []),
    (["demo", "--config", "{binyaml}", "--out", "{tmp}/o"], ["{tmp}/o"], []),
    (["lens-report", "cooke_triplet", "--out", "{garbage}"], [], ["{garbage}"]),
    (["synth", "--config", "{emptylist}", "--out", "{tmp}/s", "--count", "1"], ["{tmp}/s"], []),
]


@pytest.mark.parametrize("case", range(len(LEFTOVERS)))
def test_bad_input_leaves_no_output_and_keeps_the_inputs(case, places, capfd, monkeypatch):
    monkeypatch.delenv("ISETTORCH_DEBUG", raising=False)
    args, absent, kept = LEFTOVERS[case]
    args = [a.format(**places) for a in args]
    before = {k: open(k.format(**places), "rb").read() for k in kept}
    assert _main(args) == 2
    out, err = capfd.readouterr()
    assert len(err.splitlines()) == 1, err
    assert out == "", out  # (lens-report: no table before its error)
    for path in absent:
        assert not os.path.exists(path.format(**places)), f"{args}: left {path.format(**places)}"
    for k, data in before.items():
        assert open(k.format(**places), "rb").read() == data, f"{args}: overwrote the input {k}"


def test_argparse_errors_are_one_line_and_help_is_unchanged(capsys):
    for argv, head in ((["nope"], "isettorch: error: "), (["demo", "--size", "abc"], "isettorch demo: error: "),
                       (["synth", "--count", "2"], "isettorch synth: error: ")):
        assert _main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and err.startswith(head) and "--help)" in err, err
    assert _main(["demo", "--help"]) == 0
    assert capsys.readouterr().out.startswith("usage: isettorch demo")


@pytest.mark.parametrize(("command", "case"), PARAMS)
def test_bad_input_is_one_line_and_exit_code_2(command, case, places, capfd, monkeypatch):
    monkeypatch.delenv("ISETTORCH_DEBUG", raising=False)
    cases = _cases(command)
    if not cases:
        pytest.fail(f"isettorch {command} has no positional argument for the generic bad-input case: add its "
                    f"bad input to CASES in {__file__}")
    args, named = cases[case]
    args = [a.format(**places) for a in args]
    code = _main([command, *args])
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


def test_broken_pipe_is_not_an_input_error(monkeypatch, capsys):
    """A reader that closes stdout (`isettorch ... | head`) is not bad input: no message, exit 128 + SIGPIPE."""
    from isettorch.commands import calibrate

    def closed_pipe(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.delenv("ISETTORCH_DEBUG", raising=False)
    monkeypatch.setattr(calibrate, "run", closed_pipe)
    assert main(["calibrate", "anything"]) == 141
    assert capsys.readouterr().err == ""


def test_an_error_leaves_no_progress_bar_behind():
    """A bar open when an error reaches the CLI: on a terminal its line is cleared before the message; elsewhere
    (logs, pipes) nothing was drawn; a bar that ends well shows its final state once."""
    import io

    from isettorch._progress import abandon_bars, progress

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    tty, log = Terminal(), io.StringIO()
    bars = [progress(total=3, desc="render", file=f) for f in (tty, log)]
    for bar in bars:
        bar.update(1)
    abandon_bars()
    assert "render" in tty.getvalue() and tty.getvalue().split("\r")[-2].strip() == ""  # drawn, then blanked
    assert log.getvalue() == ""
    with pytest.raises(ValueError), progress(total=2, desc="render", file=log) as bar:
        raise ValueError("a bad frame")
    assert log.getvalue() == ""
    assert list(progress(range(2), desc="render", file=log)) == [0, 1]
    assert log.getvalue().count("2/2") == 1 and log.getvalue().endswith("\n")
