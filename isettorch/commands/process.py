"""``isettorch process RAW...``: demosaic and denoise a camera's raw frames with a joint network trained for it.

Example::

    isettorch process frames/*.png --camera cam1.yaml --model out/cam1_joint/best.pt --out processed/

``--camera`` is the camera config the model was trained for (``data.camera_config`` of
``training/train_demosaic.py``; its ``sensor:`` section written by ``isettorch calibrate --out``). Each frame (DN:
16-bit PNG/TIFF, ``.npy`` or a camera raw, read by :func:`isettorch.io.frames.read_frame`) is normalised with the
sensor's black and white levels, ``x = (DN - black) / (white - black)``, and given to the network with the noise
inputs of the sensor's Poisson-Gaussian model ``var(x) = a x + b`` (:func:`noise_params`), as in training. Output:
camera RGB relative to the white level (not white-balanced), ``<stem>.npy`` (float32 ``[3, H, W]``), ``.exr``
(linear) or ``.png`` (clipped to [0, 1] and sRGB-encoded, for viewing).
"""

from __future__ import annotations

from .._progress import add_quiet_argument

FORMATS = ("npy", "exr", "png")


def register(sub) -> None:
    p = sub.add_parser("process", help="demosaic + denoise raw frames with a joint network trained for the camera")
    p.add_argument("raw", nargs="+", metavar="RAW", help="raw frames in DN (16-bit PNG/TIFF, .npy, DNG/camera raw)")
    p.add_argument("--camera", required=True, metavar="CAMERA.yaml",
                   help="the camera config the model was trained for (sensor: black level, ADC, gain, noise)")
    p.add_argument("--model", required=True, metavar="CKPT",
                   help="a joint denoise+demosaic DemosaicNet checkpoint (training/train_demosaic.py, noise on)")
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
    per electron over the span (shot noise), ``b`` from :func:`isettorch.sensor.noise.poisson_gaussian_floor`
    (read noise, DSNU, dark-current shot noise, quantisation): the ``noise_gain`` / ``noise_floor_var`` of
    :class:`isettorch.data.PairStream`'s metadata, which the joint network was trained with. Row/column noise and
    PRNU are not in the model."""
    from ..sensor.noise import poisson_gaussian_floor

    if sensor.adc_bits is None:
        raise ValueError("camera: the sensor has no ADC (adc_bits null); expected a sensor that outputs DN")
    if not exposure_s >= 0:
        raise ValueError(f"exposure_s: expected a non-negative exposure in seconds, got {exposure_s}")
    if analog_gain is not None and not analog_gain > 0:
        raise ValueError(f"analog_gain: expected a positive gain, got {analog_gain}")
    span = float(sensor.white_level_dn) - float(sensor.black_level_dn)
    a = float(sensor.gain_per_electron(analog_gain)[0]) / span
    cg = float(sensor.conversion_gain_v_per_e)
    read_e, dsnu_e = float(sensor.read_noise_v) / cg, float(sensor.dsnu_sigma_v) / cg
    return a, float(poisson_gaussian_floor(a, read_e, dsnu_e, float(sensor.dark_current_e_per_s), exposure_s, span))


def _load(args):
    from pathlib import Path

    from ..camera import Camera
    from ..isp.learned import BAYER_PATTERNS, load_checkpoint

    try:
        camera = Camera.from_config(args.camera)
    except (OSError, ValueError, TypeError) as err:
        raise ValueError(f"camera: {args.camera}: {err}") from err
    sensor = camera.sensor
    pattern = "".join("".join(r) for r in sensor.cfa.cell)
    if pattern not in BAYER_PATTERNS:
        raise ValueError(f"camera: the sensor's CFA must be a Bayer pattern {BAYER_PATTERNS}, got {pattern!r}")
    if not Path(args.model).is_file():
        raise FileNotFoundError(f"model: no such checkpoint {args.model!r}")
    try:
        net, _ = load_checkpoint(args.model)
    except Exception as err:  # torch.load's unpickling errors too: the file is not a checkpoint (input, not a bug)
        first = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise ValueError(f"model: {args.model}: not a DemosaicNet checkpoint ({first})") from err
    if net.noise_inputs != 2:
        raise ValueError(f"model: {args.model} takes {net.noise_inputs} noise inputs; expected a joint denoise+demosaic"
                         f" network (2: sqrt(a), sqrt(b); trained with noise.enabled: true)")
    return sensor, pattern, net


def process_frame(dn, sensor, pattern: str, net, *, analog_gain=None, exposure_s: float = 0.0,
                  self_ensemble: bool = False):
    """One raw frame ``[H, W]`` in DN -> camera RGB ``[3, H, W]`` (float32, relative to the white level) by the joint
    network ``net`` with the sensor's noise inputs (:func:`noise_params`)."""
    import torch

    from ..isp.learned import demosaic_learned, noise_features

    a, b = noise_params(sensor, analog_gain, exposure_s)
    span = float(sensor.white_level_dn) - float(sensor.black_level_dn)
    x = (torch.as_tensor(dn, dtype=torch.float64) - float(sensor.black_level_dn)) / span
    with torch.no_grad():
        out = demosaic_learned(x[None, None].float(), pattern, model=net, noise=noise_features(a, b).float(),
                               self_ensemble=self_ensemble)
    return out[0]


def run(args) -> int:
    from pathlib import Path

    import numpy as np

    from .._progress import progress
    from ..io.frames import read_frame
    from ..io.images import write_image

    for f in args.raw:
        if not Path(f).is_file():
            raise FileNotFoundError(f"RAW: no such raw frame {f!r}")
    if args.analog_gain is not None and not args.analog_gain > 0:
        raise ValueError(f"analog_gain: expected a positive gain, got {args.analog_gain}")
    if not args.exposure_s >= 0:
        raise ValueError(f"exposure_s: expected a non-negative exposure in seconds, got {args.exposure_s}")
    sensor, pattern, net = _load(args)
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    with progress(total=len(args.raw), desc="process", unit="frame", quiet=args.quiet) as bar:
        for f in args.raw:
            dn = read_frame(f)
            if min(dn.shape) < 4:  # (an odd height or width is completed to whole cells by demosaic_learned)
                raise ValueError(f"RAW: {f}: expected a {pattern} mosaic of at least 4 x 4 pixels, got "
                                 f"{dn.shape[0]} x {dn.shape[1]}")
            rgb = process_frame(dn, sensor, pattern, net, analog_gain=args.analog_gain,
                                exposure_s=args.exposure_s, self_ensemble=args.self_ensemble)
            path = out_dir / f"{Path(f).stem}.{args.format}"
            if args.format == "npy":
                np.save(path, rgb.numpy().astype(np.float32), allow_pickle=False)
            elif args.format == "exr":
                write_image(path, rgb, bits=32)
            else:
                write_image(path, rgb, encoding="srgb", clip=True)
            written.append(path)
            bar.update(1)
    for p in written:
        print(p)
    return 0
