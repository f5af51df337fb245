"""``isettorch demosaic-eval DIR --method NAME``: CPSNR of a demosaic method on a folder of 8-bit images, with the
benchmark convention of shared/data/README.md (ground truth = image / 255 as linear; Bayer mosaic; output clipped
to [0, 1]; CPSNR over the three channels, averaged over images; ``--crop`` excludes a border). ``--noise-sigma`` /
``--noise-shot`` add seeded Poisson-Gaussian noise to the mosaic, ``--denoise`` runs a classical denoiser before a
classical demosaic, ``--model`` scores a user's own network (see :mod:`isettorch.isp.evaluation`)."""

from __future__ import annotations

import json

from .._progress import add_quiet_argument
from ._outputs import strict_json

# Static (the parser is built without importing torch); tests check they equal isp.evaluation's lists.
METHOD_NAMES = ("bilinear", "bilinear_colour", "learned", "learned_small", "learned_tiny", "malvar2004", "menon2007",
                "nearest")
DENOISER_NAMES = ("nlmeans", "bm3d")


def register(sub) -> None:
    p = sub.add_parser("demosaic-eval", help="score a demosaic method (CPSNR, ms/image) on a folder of 8-bit images")
    p.add_argument("folder", metavar="DIR", help="folder of 8-bit RGB .png/.tif/.jpg images")
    p.add_argument("--method", default=None,
                   help=f"one of {', '.join(METHOD_NAMES)} (default bilinear; bilinear_colour: colour-demosaicing's "
                        f"border; learned: the shipped network, its joint denoise variant when noise is asked for)")
    p.add_argument("--model", default=None, metavar="FILE",
                   help="score your own network instead of --method: a TorchScript archive, a DemosaicNet "
                        "checkpoint, or a state dict with --model-class (read with torch.load(weights_only=True))")
    p.add_argument("--model-class", default=None, metavar="MODULE:CLASS",
                   help="class of a state-dict --model, e.g. mypkg.nets:MyDemosaic (importable from PYTHONPATH)")
    p.add_argument("--model-kwargs", default=None, metavar="JSON", help="keyword arguments of --model-class (JSON)")
    p.add_argument("--pattern", default="RGGB", help="Bayer pattern of the simulated mosaic (default RGGB)")
    p.add_argument("--crop", type=int, default=0, help="border excluded from the score, pixels (default 0)")
    p.add_argument("--noise-sigma", type=float, default=0.0, metavar="S",
                   help="Gaussian noise std on the [0, 1] mosaic (default 0: noise-free)")
    p.add_argument("--noise-shot", type=float, default=0.0, metavar="A",
                   help="Poisson shot-noise gain: variance A x + S^2 (Foi et al. 2008; default 0)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--denoise", choices=DENOISER_NAMES, default=None,
                   help="denoise the noisy mosaic before a classical demosaic (nlmeans: scikit-image; bm3d: the "
                        "bm3d package, non-commercial licence, install it yourself)")
    p.add_argument("--dtype", choices=("float32", "float64"), default="float32", help="compute dtype (float32)")
    p.add_argument("--device", default="cpu", help="torch device (default cpu)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    ensemble = p.add_mutually_exclusive_group()  # (both given: the last one silently won)
    ensemble.add_argument("--self-ensemble", action="store_const", const="transpose", default=None,
                          help="learned method or a DemosaicNet --model: average the network on the mosaic and its "
                               "transpose (two passes)")
    ensemble.add_argument("--dihedral-ensemble", dest="self_ensemble", action="store_const", const="dihedral",
                          help="like --self-ensemble, over the eight flips and transposes of the mosaic (eight "
                               "passes)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_quiet_argument(p)
    p.set_defaults(func=run)


def _check_args(args) -> None:
    """Bad input named by its argument (``DIR``, ``--noise-sigma``, ...) before any work; ValueError otherwise."""
    from pathlib import Path

    from ..isp.denoise import _check_noise, check_denoiser

    if not Path(args.folder).is_dir():
        raise FileNotFoundError(f"DIR: no such folder {args.folder!r}")
    _check_noise(args.noise_sigma, args.noise_shot)  # its messages name noise_sigma / noise_shot: --noise-sigma, ...
    if args.denoise is not None:
        check_denoiser(args.denoise)  # (bm3d is the user's package)
    if args.crop < 0:
        raise ValueError(f"--crop: expected a border of >= 0 pixels, got {args.crop}")
    from ..isp.learned import BAYER_PATTERNS

    if args.pattern.upper() not in BAYER_PATTERNS:  # before the images are read (not blamed on DIR)
        raise ValueError(f"--pattern: expected a Bayer pattern, one of {', '.join(BAYER_PATTERNS)}, got "
                         f"{args.pattern!r}")
    if args.model is not None and args.method is not None:
        raise ValueError(f"--method/--model: --model scores your own network instead of a method; got both "
                         f"--method {args.method} and --model {args.model}")
    if args.model is not None and not Path(args.model).is_file():
        raise FileNotFoundError(f"--model: no such file {args.model!r} (expected a TorchScript archive or a "
                                f"weights file)")


def as_dir_error(err: ValueError) -> ValueError:
    """The library's error about ``images`` (:func:`isettorch.isp.evaluation.load_images` and ``check_photos``) as
    the command's argument ``DIR`` (demosaic-eval and design-eval)."""
    return ValueError(f"DIR: {str(err).removeprefix('images: ')}")


def run(args) -> int:
    import torch

    from ..isp.evaluation import check_device, evaluate_demosaic, load_demosaic_model, load_images

    _check_args(args)
    device = check_device(args.device)
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    dtype = getattr(torch, args.dtype)
    try:  # read the images first: a bad one is named with DIR (the library's message names "images")
        images = load_images(args.folder)
    except ValueError as err:
        raise as_dir_error(err) from err
    model = None
    if args.model is not None:
        kwargs = None
        if args.model_kwargs is not None:
            try:
                kwargs = json.loads(args.model_kwargs)
            except json.JSONDecodeError as err:
                raise ValueError(f"--model-kwargs: expected a JSON object, got {args.model_kwargs!r} ({err})") from err
            if not isinstance(kwargs, dict):
                raise ValueError(f"--model-kwargs: expected a JSON object, got {args.model_kwargs!r}")
        model = load_demosaic_model(args.model, args.model_class, kwargs=kwargs, device=device, dtype=dtype)
    elif args.model_class is not None or args.model_kwargs is not None:
        raise ValueError("--model-class/--model-kwargs: only with --model FILE")
    extra = {"self_ensemble": args.self_ensemble} if args.self_ensemble else {}  # evaluate_demosaic checks the method
    try:
        method = "bilinear" if args.method is None else args.method  # ("" is refused by evaluate_demosaic)
        res = evaluate_demosaic(images, method, args.pattern.upper(), args.crop, dtype=dtype,
                                device=device, noise_sigma=args.noise_sigma, noise_shot=args.noise_shot,
                                seed=args.seed, denoise=args.denoise, model=model, progress=not args.quiet, **extra)
    except ValueError as err:  # an image the method cannot take (e.g. under 4 pixels for a network): named with DIR
        if not str(err).startswith("images: "):
            raise
        raise as_dir_error(err) from err
    if args.json:  # JSON has no inf: an exact image's cpsnr is null beside "exact": true
        print(strict_json(res, indent=2))
        return 0
    noise = (f"  noise sigma {res['noise_sigma']:g} shot {res['noise_shot']:g} seed {res['seed']}"
             if res["noise_sigma"] or res["noise_shot"] else "")
    den = f"  denoise {res['denoise']}" if res["denoise"] else ""
    network = f" ({res['network']} network)" if res.get("network") else ""
    print(f"method {res['method']}{network}  pattern {res['pattern']}  crop {res['crop']}  "
          f"({args.dtype}, {args.device}){noise}{den}")
    for item in res["images"]:
        print(f"  {item['name']:<24s} {item['cpsnr']:8.3f} dB  {item['ms']:8.1f} ms"
              + ("  (reproduced exactly)" if item["exact"] else ""))
    n, exact = len(res["images"]), res["exact_images"]
    if exact == n:
        over = f"(all {n} images reproduced exactly)"
    elif exact:
        over = f"over {n - exact} of {n} images ({exact} reproduced exactly, CPSNR inf, not averaged)"
    else:
        over = f"over {n} images"
    print(f"mean CPSNR {res['mean_cpsnr']:.3f} dB {over}, {res['ms_per_image']:.1f} ms/image, "
          f"{res['ms_per_megapixel']:.1f} ms/MP")
    return 0
