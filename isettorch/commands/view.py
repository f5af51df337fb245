"""``isettorch view``: ISET's four windows (scene, optical image, sensor, image processor) in a browser.

Drag a region on any image to see its spectral radiance or irradiance, the optics' PSF and MTF, the raw pixel
histogram and SNR, and the processed image's chromaticity and CIEDE2000 (Macbeth); change f-number, exposure,
pixel size, CFA, noise and demosaic and the windows re-render. Needs the ``viewer`` extra (Bokeh).
"""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("view", help="ISET's scene / optics / sensor / processor windows in a browser (needs the "
                                    "'viewer' extra)")
    p.add_argument("--config", default="default", help="camera preset name or YAML file (default: default)")
    p.add_argument("--scene", default="macbeth",
                   help="built-in scene (macbeth, slanted_edge, frequency_sweep, zone_plate, star, dead_leaves, "
                        "point_array, grid_lines, checkerboard, uniform_d65) or a file (.mat, .exr, .png, .jpg, .tif)")
    p.add_argument("--size", type=int, default=256, help="scene size in samples (default 256)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--port", type=int, default=5006, help="port (default 5006)")
    p.add_argument("--address", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser tab")
    p.set_defaults(func=run)


def run(args) -> int:
    import sys

    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port: expected 0..65535, got {args.port}")
    if args.size < 16:
        raise ValueError(f"--size: expected at least 16 samples, got {args.size}")
    try:
        import bokeh  # noqa: F401
    except ImportError:
        print("isettorch view: needs Bokeh; install the viewer extra: pip install 'isettorch[viewer]'", file=sys.stderr)
        return 2
    from ..viewer import serve

    try:  # ValueError / OSError (a bad --config or --scene): one line and exit code 2 (isettorch.cli)
        serve(args.config, args.scene, args.size, args.seed, port=args.port, address=args.address,
              open_browser=not args.no_browser)
    except TypeError as err:  # a config value of the wrong type
        raise ValueError(f"--config {args.config}: {err}") from err
    return 0
