"""``isettorch design-eval DESIGN DIR [--lux L ...] [--seed S] [--noise-free] [--json]``: score a camera design
(filters, mosaic and reconstruction network, :mod:`isettorch.design`) on a folder of 8-bit RGB photographs, each
lifted to spectra (the photograph as a reflectance under D65, Mallett & Yuksel's sRGB basis) and rendered through the
design's camera at each light level with the same noise seed for every design: per-image and mean CPSNR against the
photograph in sRGB (crop 10, the demosaic scoring convention) and mean CIEDE2000; ``--noise-free`` also the same
network's mean CPSNR on the noise-free capture.

Each photograph sets the sensor's size (one scene sample per pixel), so a large one is a wide-angle capture whose
corners get little light through the design's lens (cos^4: 0.81 of the centre's at 768 x 512, 0.06 at 4000 x 3000);
the command notes photographs whose corners get less than half, whose low-light scores then measure that falloff
as much as the sensor. It also notes photographs whose embedded ICC profile is not sRGB (Display P3, Adobe RGB):
their code values are lifted as sRGB.

DESIGN is a shipped name (bayer_rgb, ycmy, rgbw, learned) or a design file's path (``./name`` for a file named like
a shipped design).

``--json`` prints ``{"design", "lux": [levels], "seed", "crop", "mean_cpsnr": {"<lux>": dB}, "mean_de2000":
{"<lux>": value}, "images": [{"name", "corner_light", "cpsnr": {...}, "de2000": {...}}, ...]}`` (with
``--noise-free`` also ``"mean_cpsnr_noise_free"`` and each image's ``"cpsnr_noise_free"``). Image ``i`` of the
folder (sorted by name) draws its noise from a generator seeded with ``(seed, i, lux)``, the same seed for every
design (the same design gives the same draw; two designs' shot noise takes a number of draws that depends on their
signals, so their later draws differ), so adding a photograph that sorts before it changes its noise realisation."""

from __future__ import annotations

import sys

from .._progress import add_quiet_argument
from ._outputs import strict_json

# Static (the parser is built without importing torch); a test checks it equals isettorch.design's list.
SHIPPED_NAMES = ("bayer_rgb", "ycmy", "rgbw", "learned")
#: below this corner irradiance (relative to the centre's) the command notes the photograph's lens falloff
DARK_CORNER = 0.5


def register(sub) -> None:
    p = sub.add_parser("design-eval", help="score a camera design (filters, mosaic, network) on a folder of photos")
    p.add_argument("design", metavar="DESIGN",
                   help=f"a design file (.pt) or a shipped design: {', '.join(SHIPPED_NAMES)}")
    p.add_argument("folder", metavar="DIR", help="folder of 8-bit RGB .png/.tif/.jpg photographs")
    # (extend: --lux 10 --lux 100 scores both; the last one alone was scored)
    p.add_argument("--lux", type=float, nargs="+", action="extend", default=None, metavar="L",
                   help="scene illuminance(s) in lux, among the levels the design was trained for (it has a network "
                        "for each; the shipped designs: 1, 10, 100); default: all of them")
    p.add_argument("--seed", type=int, default=0, help="noise seed, the same for every design (default 0)")
    p.add_argument("--crop", type=int, default=10, help="border excluded from the scores, pixels (default 10)")
    p.add_argument("--device", default="cpu", help="torch device (default cpu)")
    p.add_argument("--noise-free", action="store_true",
                   help="also score the noise-free capture through the same network (the error noise does not cause)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table (keys: design, "
                   "lux, seed, crop, mean_cpsnr, mean_de2000, images)")
    add_quiet_argument(p)
    p.set_defaults(func=run)


def _note_profiles(folder) -> None:
    """A note naming the photographs whose embedded ICC profile (Display P3, Adobe RGB, ...) or PNG gAMA / cHRM is not
    sRGB's (:func:`isettorch.io.images.non_srgb_photos`)."""
    from ..io.images import non_srgb_photos, photo_files

    try:
        files = photo_files(folder)
    except ValueError:  # a folder the evaluation refuses, naming it as DIR
        return
    note = non_srgb_photos(files)
    if note is not None:
        print(f"isettorch design-eval: note: {note}", file=sys.stderr)


def run(args) -> int:
    from pathlib import Path

    from ..design import evaluate_design
    from .demosaic_eval import as_dir_error

    if Path(args.folder).is_dir():  # (before the renders: a photograph the note cannot open fails at once)
        _note_profiles(args.folder)
    try:
        res = evaluate_design(args.design, args.folder, args.lux, seed=args.seed, crop=args.crop, device=args.device,
                              noise_free=args.noise_free, progress=not args.quiet)
    except ValueError as err:  # the library's "images" (the folder, an unreadable or too small photo) is DIR here
        if not str(err).startswith("images: "):
            raise
        raise as_dir_error(err) from err
    dark = [item for item in res["images"] if item["corner_light"] < DARK_CORNER]
    if dark:
        worst = min(dark, key=lambda item: item["corner_light"])
        print(f"isettorch design-eval: note: {len(dark)} photograph(s) make a wide-angle capture on this camera (one "
              f"scene sample per pixel), with corners at less than {DARK_CORNER:g} of the centre's light (cos^4; "
              f"{worst['name']}: {worst['corner_light']:.2f}); their low-light scores measure that falloff as much as "
              f"the sensor: downscale them to compare sensors", file=sys.stderr)
    if args.json:
        print(strict_json(res, indent=2))
        return 0
    keys = list(res["mean_cpsnr"])
    print(f"design {res['design']}  seed {res['seed']}  crop {res['crop']}  (CPSNR dB / mean dE2000)")
    print(f"  {'image':<24s}" + "".join(f"{k + ' lux':>20s}" for k in keys))
    for item in res["images"]:
        print(f"  {item['name']:<24s}" + "".join(f"{item['cpsnr'][k]:11.2f} / {item['de2000'][k]:6.2f}"
                                                  for k in keys))
    print(f"  {'mean':<24s}" + "".join(f"{res['mean_cpsnr'][k]:11.2f} / {res['mean_de2000'][k]:6.2f}" for k in keys))
    if args.noise_free:
        print(f"  {'mean, noise-free capture':<24s}" + "".join(f"{res['mean_cpsnr_noise_free'][k]:11.2f}" + " " * 9
                                                             for k in keys))
    return 0
