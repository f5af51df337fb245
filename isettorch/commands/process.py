"""``isettorch process RAW...``: demosaic and denoise a camera's raw frames with a joint network trained for it.

Example::

    isettorch process frames/*.png --camera cam1.yaml --model out/cam1_joint/best.pt --out processed/

``--camera`` is the camera config the model was trained for (``data.camera_config`` of
``training/train_demosaic.py``; its ``sensor:`` section written by ``isettorch calibrate --out``). Each frame (DN:
16-bit PNG/TIFF, ``.npy`` or a camera raw, read by :func:`isettorch.io.frames.read_frame`) is normalised with the
sensor's black and white levels at the frames' gain, ``x = (DN - black) / (white - black)``, black being the
sensor's zero level (its black level plus any analog offset, as the training pairs normalise; a camera raw's own CFA,
black levels and white level must be the config's: a file that disagrees, or a monochrome raw, is refused), and given
to the network with the noise inputs of the sensor's Poisson-Gaussian model ``var(x) = a x + b``
(:func:`noise_params`), as in training. Output:
camera RGB relative to the white level (not white-balanced), ``<stem>.npy`` (float32 ``[3, H, W]``), ``.exr``
(linear) or ``.png`` (clipped to [0, 1] and sRGB-encoded, for viewing), turned as a camera raw's orientation says
(a DNG's Orientation tag, LibRaw's flip for other raws: a portrait frame comes out upright; PNG, TIFF and ``.npy``
frames as stored).
"""

from __future__ import annotations

import math
import sys

from .._progress import add_quiet_argument

FORMATS = ("npy", "exr", "png")


def register(sub) -> None:
    p = sub.add_parser("process", help="demosaic + denoise raw frames with a joint network trained for the camera")
    p.add_argument("raw", nargs="+", metavar="RAW", help="raw frames in DN (16-bit PNG/TIFF, .npy, DNG/camera raw)")
    p.add_argument("--camera", required=True, metavar="CAMERA.yaml",
                   help="the camera config the model was trained for (sensor: black level, ADC, gain, noise)")
    p.add_argument("--model", required=True, metavar="CKPT",
                   help="a joint denoise+demosaic DemosaicNet checkpoint (training/train_demosaic.py, noise on); "
                        "the shipped isettorch/assets/demosaic_learned_denoise.pt runs with its shipped gates")
    p.add_argument("--out", default="processed", metavar="DIR", help="output folder (default: processed)")
    p.add_argument("--format", default="npy", choices=FORMATS,
                   help="npy (float32 [3, H, W], linear), exr (linear) or png (clipped, sRGB-encoded); default npy")
    p.add_argument("--analog-gain", type=float, default=None,
                   help="the frames' analog gain (default: the camera config's)")
    p.add_argument("--exposure-s", type=float, default=0.0,
                   help="the frames' exposure (s), for the dark-current shot noise in the noise model (default 0)")
    p.add_argument("--self-ensemble", action="store_true", help="average the network over the mosaic's transpose")
    add_quiet_argument(p)
    p.set_defaults(func=run)


def noise_params(sensor, analog_gain=None, exposure_s: float = 0.0) -> tuple[float, float]:
    """``(a, b)`` of the Poisson-Gaussian model ``var(x) = a x + b`` of a sensor's frames in normalised units
    (``x = (DN - black) / (white - black)``; Foi et al., IEEE TIP 17(10) 2008; EMVA 1288 eq. 6): ``a`` the output
    per electron over the span (shot noise), ``b`` the sensor's own floor over the span squared
    (:meth:`isettorch.sensor.Sensor.poisson_gaussian`: read noise, twice with CDS, DSNU unless CDS, dark-current shot
    noise, row/column noise, quantisation): the ``noise_gain`` / ``noise_floor_var`` of
    :class:`isettorch.data.PairStream`'s metadata, which the joint network was trained with. PRNU is not in the
    model. Both are finite and give finite float32 noise inputs
    (:func:`isettorch.isp.learned.noise_features`), else a ValueError names the setting that takes them out
    (``analog_gain``, ``exposure_s``, or ``camera`` for the config's gain)."""
    from ..isp.learned import noise_features

    if sensor.adc_bits is None:
        raise ValueError("camera: the sensor has no ADC (adc_bits null); expected a sensor that outputs DN")
    if sensor.output_units != "dn":  # (its noise model and levels would be in those units, the frames in DN)
        raise ValueError(f"camera: the sensor outputs {sensor.output_units} (sensor.output_units); expected a sensor "
                         f"that outputs DN")
    _check_settings(analog_gain, exposure_s)
    gain = "camera: the config's analog gain" if analog_gain is None else f"analog_gain: the gain {analog_gain:g}"

    def fits(a_, b_) -> tuple[bool, bool]:  # each parameter finite and its float32 noise input too
        ok = [math.isfinite(a_), math.isfinite(b_)]
        f = noise_features(a_ if ok[0] else 0.0, b_ if ok[1] else 0.0).float().isfinite()[0]
        return ok[0] and bool(f[0]), ok[1] and bool(f[1])

    per_e = float(sensor.gain_per_electron(analog_gain)[0])  # (checks the gain: one positive value)
    span = levels(sensor, analog_gain)[1]
    a = per_e / span
    if not fits(a, 0.0)[0]:
        raise ValueError(f"{gain} makes the noise model's shot gain a {a:.3g} (normalised units per electron), beyond "
                         f"the network's float32 noise input; expected the frames' real gain")
    dark = float(sensor.dark_current_e_per_s)

    def floor(t):  # float64 tensors: a huge gain gives inf, not an OverflowError
        return float(sensor.poisson_gaussian(exposure_s=t, analog_gain=analog_gain)[1][0]) / span ** 2

    if a >= 1:  # one electron spans the whole signal range: no camera's real setting (gain 1e30 wrote a constant)
        raise ValueError(f"{gain} makes one electron {a:.3g} of the signal's span (the noise model's shot gain a >= 1);"
                         f" expected the frames' real gain")
    b = floor(exposure_s)
    if math.isfinite(b) and b >= 1:  # a noise floor wider than the span (exposure 1e30 s wrote a constant)
        what = gain if floor(0.0) >= 1 else f"exposure_s: {exposure_s:g} s of the sensor's dark current ({dark:g} e/s)"
        raise ValueError(f"{what} makes the noise floor's standard deviation {math.sqrt(b):.3g} of the signal's span "
                         f"(b >= 1); expected the frames' real settings")
    if not fits(a, b)[1]:
        b0 = floor(0.0)
        if not fits(a, b0)[1]:  # the read noise alone: the gain
            raise ValueError(f"{gain} makes the noise model's read variance b {b:.3g}, beyond the network's float32 "
                             f"noise input; expected the frames' real gain")
        raise ValueError(f"exposure_s: {exposure_s:g} s of the sensor's dark current ({dark:g} e/s) makes the noise "
                         f"model's variance b {b:.3g}, beyond the network's float32 noise input; expected the "
                         f"frames' exposure in seconds")
    return a, b


def levels(sensor, analog_gain=None) -> tuple[float, float]:
    """``(black, span)`` in DN of a sensor's frames at ``analog_gain`` (None: the config's), as the training pairs
    normalise a capture (``RawImage.levels``): black its zero level, the black level plus any analog offset after the
    gain (:meth:`isettorch.sensor.Sensor.zero_level`; the offset is not signal), span the white level at that gain
    less it. ValueError naming the gain when the white level is not above the zero level (an offset filling the
    range, or a gain that leaves the full well under black)."""
    black, white = float(sensor.zero_level(analog_gain)), float(sensor.white_level(analog_gain))
    if not white > black:
        gain = "camera: the config's analog gain" if analog_gain is None else f"analog_gain: the gain {analog_gain:g}"
        offset = f", its analog offset of {sensor.analog_offset_v:g} V included" if sensor.analog_offset_v else ""
        raise ValueError(f"{gain} puts the sensor's white level, {white:g} DN, at or below its zero level, {black:g} "
                         f"DN{offset}; expected the frames' real gain")
    return black, white - black


def _check_settings(analog_gain, exposure_s) -> None:
    """The frames' analog gain (None: the camera config's) and exposure: finite, the gain > 0, the exposure >= 0."""
    if analog_gain is not None and not (math.isfinite(analog_gain) and analog_gain > 0):
        raise ValueError(f"analog_gain: expected a finite positive gain, got {analog_gain}")
    if not (math.isfinite(exposure_s) and exposure_s >= 0):
        raise ValueError(f"exposure_s: expected a finite exposure >= 0 in seconds, got {exposure_s}")


def _load(args):
    import filecmp
    from pathlib import Path

    from .._checks import first_line
    from ..camera import Camera
    from ..isp.learned import BAYER_PATTERNS, PRETRAINED, load_checkpoint, load_pretrained

    try:
        camera = Camera.from_config(args.camera)
    except (OSError, ValueError, TypeError) as err:
        message = str(err)
        for head in ("path: ", "config: "):  # load_config's own messages name the file already
            if message.startswith(head):
                raise ValueError(f"camera: {message.removeprefix(head)}") from err
        raise ValueError(f"camera: {args.camera}: {message}") from err
    sensor = camera.sensor
    pattern = "".join("".join(r) for r in sensor.cfa.cell)
    if pattern not in BAYER_PATTERNS:
        raise ValueError(f"camera: the sensor's CFA must be a Bayer pattern {BAYER_PATTERNS}, got {pattern!r}")
    if Path(args.model).is_dir():
        raise ValueError(f"model: {args.model} is a folder; expected a checkpoint file (.pt)")
    if not Path(args.model).is_file():
        raise FileNotFoundError(f"model: no such checkpoint {args.model!r}")
    try:
        shipped = filecmp.cmp(args.model, PRETRAINED["joint_denoise"], shallow=False)
        if shipped:
            # the shipped joint network (the file, or a copy of it) as it ships: with its guard and its low- and
            # high-noise gates (its bare checkpoint differed from demosaic_learned(variant='joint_denoise') by 0.12 on
            # a noisy frame)
            net = load_pretrained("joint_denoise")
        else:
            net, _ = load_checkpoint(args.model)
    except Exception as err:  # torch.load's unpickling errors too: the file is not a checkpoint (input, not a bug)
        raise ValueError(f"model: {args.model}: not a DemosaicNet checkpoint ({first_line(err)})") from err
    if net.noise_inputs != 2:
        raise ValueError(f"model: {args.model} takes {net.noise_inputs} noise inputs; expected a joint denoise+demosaic"
                         f" network (2: sqrt(a), sqrt(b); trained with noise.enabled: true)")
    return sensor, pattern, net, shipped


def process_frame(dn, sensor, pattern: str, net, *, analog_gain=None, exposure_s: float = 0.0,
                  self_ensemble: bool = False):
    """One raw frame ``[H, W]`` in DN -> camera RGB ``[3, H, W]`` (float32, relative to the white level) by the joint
    network ``net`` with the sensor's noise inputs (:func:`noise_params`)."""
    import torch

    from ..isp.learned import demosaic_learned, noise_features

    a, b = noise_params(sensor, analog_gain, exposure_s)
    black, span = levels(sensor, analog_gain)
    x = (torch.as_tensor(dn, dtype=torch.float64) - black) / span
    with torch.no_grad():
        out = demosaic_learned(x[None, None].float(), pattern, model=net, noise=noise_features(a, b).float(),
                               self_ensemble=self_ensemble)
    if not bool(torch.isfinite(out).all()):  # never written as a NaN image
        raise ValueError(f"raw: the network returned {int((~torch.isfinite(out)).sum())} NaN/inf values (noise model "
                         f"a = {a:.3g}, b = {b:.3g}); expected the frames' real analog gain and exposure")
    return out[0]


def _check_white_level(f, file_white: float, sensor, analog_gain, adc_bits: int) -> None:
    """A camera raw's white level against the camera config's: above the config's largest ADC code the file has more
    bits than the camera; more than 2 % of the span below the config's white level it clips where the config does
    not (a 10-bit DNG through a 12-bit config: a clipped frame came out at 0.24 of white, exit 0). Above the
    config's white level is the camera's (a DNG states the ADC's top code where the full well clips first)."""
    black, span = levels(sensor, analog_gain)
    code_max = float(2 ** adc_bits - 1)
    at = "" if analog_gain is None else f" at --analog-gain {analog_gain:g}"
    if file_white >= code_max + 1:  # (left-aligned: 65535 / 16 = 4095.94 for 12 bits)
        raise ValueError(f"RAW: {f}: the file's white level {file_white:g} DN is above the camera config's largest "
                         f"ADC code {code_max:g} DN ({adc_bits} bits; --camera: sensor.adc_bits)")
    if file_white < black + 0.98 * span:
        raise ValueError(f"RAW: {f}: the file's white level {file_white:g} DN is below the camera config's "
                         f"{black + span:g} DN{at} (its clipped pixels would come out at "
                         f"{(file_white - black) / span:.3g} of white); process it with its own camera's config")


def _read(f):
    """:func:`isettorch.io.frames.read_frame_data` of a RAW argument, its errors naming RAW."""
    from ..io.frames import read_frame_data

    try:
        return read_frame_data(f)
    except ValueError as err:  # the reader names the file; the argument is RAW
        raise ValueError(f"RAW: {err}") from err


def _left_alignment(raws, adc_bits: int) -> dict:
    """``{frame: step}``: for the frames stored in integer words of one width above the ADC's bits, the step
    ``2^(width - adc_bits)`` for left-aligned data, else 1. A frame with at least 32 distinct values decides for
    itself (every value a multiple of the step: left-aligned, :func:`isettorch.sensor.calibration.quantisation_step`,
    calibrate's rule; a value off the step: right-aligned); a run holding both kinds is refused (ValueError naming
    RAW: one right-aligned frame took the division from every left-aligned one, 24x too bright, exit 0). Frames
    with too few values to tell (a dark or small frame) follow the decided ones, or with none are decided together.
    A dim left-aligned frame, under the largest code, came out 11x too bright, exit 0. Where every value is a
    multiple of the step but the values are too few to tell, a warning says so. Each frame is read once here (it
    was read up to four times)."""
    from pathlib import Path

    from ..io.frames import RAW_SUFFIXES
    from ..sensor.calibration import QuantisationStep

    groups: dict = {}  # word width -> ({frame: its values' step accumulator}, their largest value)
    for f in raws:
        frame = _read(f)
        # a camera raw's codes come in 16-bit words (LibRaw's raw image): a left-aligned DNG's black level tags
        # are left-aligned too (its 128 DN read 2048) and are divided with the codes
        width = 16 if frame.stored_bits is None and Path(f).suffix.lower() in RAW_SUFFIXES else frame.stored_bits
        if width is None or width <= adc_bits:
            continue
        own, top = groups.setdefault(width, ({}, [0.0]))
        own[f] = QuantisationStep()
        own[f].add(frame.dn)
        top[0] = max(top[0], float(frame.dn.max()))
    steps = dict.fromkeys(raws, 1)
    for width in sorted(groups):
        own, top = groups[width]
        group, acc = list(own), QuantisationStep.pooled(own.values())
        step = 2 ** (width - adc_bits)
        # a frame with enough values decides for itself; frames of both kinds in one run are refused (one
        # right-aligned frame took the division from every left-aligned one: 24x too bright, exit 0)
        left = [f for f in group if own[f].step() >= step]
        # a nonzero value off the step: right-aligned (an all-zero frame, a black dark, tells nothing)
        right = [f for f in group if own[f].acc != 0 and own[f].step(min_distinct=1) < step]
        if left and right:
            raise ValueError(f"RAW: {left[0]} holds {adc_bits}-bit data left-aligned in {width}-bit words (every "
                             f"value a multiple of {step} DN) and {right[0]} does not; process them in separate runs")
        if left or (not right and acc.step() >= step):  # the undecided frames follow the decided ones, or the pool
            divided = [f for f in group if f not in right]
            steps.update(dict.fromkeys(divided, step))
            print(f"isettorch process: RAW: every value of {len(divided)} frame(s) in {width}-bit words is a multiple "
                  f"of {step} DN: {adc_bits}-bit data left-aligned, divided by {step}", file=sys.stderr)
        elif not right and acc.step(min_distinct=1) >= step and top[0] < 2 ** adc_bits:  # (above the top code:
            # refused, said there)
            print(f"isettorch process: warning: RAW: every value of {len(group)} frame(s) in {width}-bit words is a "
                  f"multiple of {step} DN, but they hold too few distinct values to tell left-aligned {adc_bits}-bit "
                  f"data; taken as right-aligned (divide them by {step} yourself if they are left-aligned)",
                  file=sys.stderr)
    return steps


def _output_paths(raws, out_dir, fmt: str) -> list:
    """``out_dir / <stem>.<fmt>`` of every frame; ValueError naming RAW when two frames would write one file (the
    same stem: frame.npy and sub/frame.npy, frame.npy and frame.tif; or a frame given twice)."""
    from pathlib import Path

    seen: dict = {}
    for f in raws:
        path = out_dir / f"{Path(f).stem}.{fmt}"
        if path in seen:
            first = seen[path]
            if Path(first).resolve() == Path(f).resolve():
                raise ValueError(f"RAW: {f} is given twice; expected each frame once")
            raise ValueError(f"RAW: {first} and {f} would both be written to {path}; expected frames with distinct "
                             f"names (stems)")
        seen[path] = f
    return list(seen)


def run(args) -> int:
    from pathlib import Path

    import numpy as np
    import torch

    from .._progress import progress
    from ..io.frames import RAW_BLACK_TOLERANCE_DN, check_sample_bits
    from ..io.images import _ORIENT, write_image
    from ._outputs import Outputs, check_dir, check_not_input

    for f in args.raw:
        if Path(f).is_dir():
            raise ValueError(f"RAW: {f} is a folder; expected raw frame files (e.g. {f}/*.npy)")
        if not Path(f).is_file():
            raise FileNotFoundError(f"RAW: no such raw frame {f!r}")
    _check_settings(args.analog_gain, args.exposure_s)
    out_dir = Path(args.out)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"out: expected a folder, {args.out} is a file")
    outputs = _output_paths(args.raw, out_dir, args.format)
    for path in outputs:  # never overwrite a frame (--out the frames' own folder, same format)
        check_not_input(path, args.raw, "out")
    check_dir(out_dir, "out")
    sensor, pattern, net, shipped = _load(args)
    noise_params(sensor, args.analog_gain, args.exposure_s)  # a setting the noise model cannot take: before any output
    adc_bits = int(sensor.adc_bits)  # (noise_params refused a sensor without an ADC)
    shifts = _left_alignment(args.raw, adc_bits)
    config_gain = float(sensor.analog_gain)
    if not shipped and args.analog_gain is not None and abs(math.log(args.analog_gain / config_gain)) > 0.01:
        # a camera-specific network learned the noise of the config's gain alone (docs: one model per ISO); at gain
        # 64 for a gain-1 camera one came out with an RMS error of 0.14, at 1000 in -4..6.8, exit 0
        print(f"isettorch process: warning: analog_gain {args.analog_gain:g} differs from the camera config's "
              f"{config_gain:g}, the gain a camera-specific network is trained at: its noise inputs are outside its "
              f"training (train or fine-tune one model per gain)", file=sys.stderr)
    written = []
    # every frame's file is written under a temporary name and moved into place once all frames succeeded: a bad
    # frame (unreadable, wrong shape, NaN) leaves neither files nor a new folder
    with Outputs(out_dir) as staged, \
            progress(total=len(args.raw), desc="process", unit="frame", quiet=args.quiet) as bar:
        for f, path in zip(args.raw, outputs):
            dn, file_cfa, file_blacks, stored_bits, delta, file_white, orientation = _read(f)
            if shifts[f] > 1:
                dn = dn / shifts[f]
                file_blacks = None if file_blacks is None else [b / shifts[f] for b in file_blacks]
                delta = None if delta is None else delta / shifts[f]
                file_white = None if file_white is None else file_white / shifts[f]
            try:  # (an 8-bit PNG read as 12-bit DN)
                check_sample_bits(f, stored_bits, adc_bits, "camera's")
            except ValueError as err:
                raise ValueError(f"RAW: {err}") from err
            # a camera raw's own metadata must be the camera config's: the network, the CFA phase and the black
            # level it is given are the config's (a GRBG DNG through an RGGB config came out grey, exit 0)
            if file_cfa is not None and file_cfa != pattern:
                raise ValueError(f"RAW: {f}: the file's CFA {file_cfa} differs from the camera config's {pattern} "
                                 f"(--camera); process it with its own camera's config")
            if file_cfa is None and file_blacks is not None:  # a camera raw without a mosaic (grey came out orange)
                raise ValueError(f"RAW: {f}: the file is a monochrome raw (no colour filter array); the camera "
                                 f"config's CFA is {pattern} (--camera)")
            if file_white is not None:
                _check_white_level(f, file_white, sensor, args.analog_gain, adc_bits)
            black = levels(sensor, args.analog_gain)[0]  # with an analog offset, the dark reading it makes
            # the config's one black level is the mean over the CFA cell (calibrate measures it from all pixels): a
            # raw whose channels have their own levels around it (128, 130, 126, 132) is the camera's (was refused)
            if file_blacks and abs(float(np.mean(file_blacks)) - black) > RAW_BLACK_TOLERANCE_DN:
                what = ("sensor.black_level_dn" if sensor.analog_offset_v == 0 else
                        f"sensor.black_level_dn {sensor.black_level_dn:g} plus analog_offset_v "
                        f"{sensor.analog_offset_v:g} V after the gain")
                at = "" if args.analog_gain is None else f" at --analog-gain {args.analog_gain:g}"
                deltas = "" if delta is None else " (with the means of its per-row / per-column deltas)"
                raise ValueError(f"RAW: {f}: the file's black levels {[round(b, 3) for b in file_blacks]} DN{deltas} "
                                 f"(mean {float(np.mean(file_blacks)):g}) differ from the camera config's {black:g} "
                                 f"DN{at} by more than {RAW_BLACK_TOLERANCE_DN:g} DN (--camera: {what})")
            if file_blacks:
                # the frame's own black level, per channel and per pixel (a DNG's BlackLevel and its per-row /
                # per-column deltas), replaced by the config's: its differences from the config's, up to the
                # tolerance, were left in the output
                from ..io.raw import black_level_map

                dn = dn - black_level_map(file_cfa, file_blacks, delta, dn.shape) + black
            if min(dn.shape) < 4:  # (an odd height or width is completed to whole cells by demosaic_learned)
                raise ValueError(f"RAW: {f}: expected a {pattern} mosaic of at least 4 x 4 pixels, got "
                                 f"{dn.shape[0]} x {dn.shape[1]}")
            # no value above the ADC's largest code (e.g. 12-bit data left-shifted into 16 bits exceeds it). Not the
            # white level: where the full well saturates below the ADC range, a real frame's saturated pixels scatter
            # around it (their gains differ). noise_params refused a sensor without an ADC
            top, code_max = float(dn.max()), float(2 ** adc_bits - 1)
            if top > code_max:
                raise ValueError(f"RAW: {f}: values up to {top:g} DN exceed the camera's largest ADC code "
                                 f"{code_max:g} DN ({adc_bits} bits; data shifted left?)")
            try:
                rgb = process_frame(dn, sensor, pattern, net, analog_gain=args.analog_gain,
                                    exposure_s=args.exposure_s, self_ensemble=args.self_ensemble)
            except ValueError as err:  # the library's "raw" is this frame
                if not str(err).startswith("raw: "):
                    raise
                raise ValueError(f"RAW: {f}: {str(err).removeprefix('raw: ')}") from err
            if orientation != 1:  # as the camera displays it (a portrait frame upright), the mosaic processed as stored
                rgb = torch.from_numpy(np.ascontiguousarray(_ORIENT[orientation](rgb.permute(1, 2, 0).numpy())))
                rgb = rgb.permute(2, 0, 1)
            tmp = staged.temporary(path)
            if args.format == "npy":
                np.save(tmp, rgb.numpy().astype(np.float32), allow_pickle=False)
            elif args.format == "exr":
                write_image(tmp, rgb, bits=32)
            else:
                write_image(tmp, rgb, encoding="srgb", clip=True)
            written.append(path)
            bar.update(1)
    for p in written:
        print(p)
    return 0
