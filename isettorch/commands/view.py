"""``isettorch view``: ISET's four windows (scene, optical image, sensor, image processor) in a browser.

Drag a region on any image to see its spectral radiance or irradiance, the optics' PSF and MTF, the raw pixel
histogram and SNR, and the processed image's chromaticity and CIEDE2000 (Macbeth); change f-number, exposure,
pixel size, CFA, noise and demosaic and the windows re-render. Needs the ``viewer`` extra (Bokeh).
"""

from __future__ import annotations

#: --size bounds: below 16 samples the charts have no patches; above 4096 the 31-band scene and optical image
#: (31 x 4096^2 float32 = 2 GB each, re-rendered at every change) no longer fit a workstation's memory
MIN_SIZE, MAX_SIZE = 16, 4096


def register(sub) -> None:
    p = sub.add_parser("view", help="ISET's scene / optics / sensor / processor windows in a browser (needs the "
                                    "'viewer' extra)")
    p.add_argument("--config", default="default", help="camera preset name or YAML file (default: default)")
    p.add_argument("--scene", default="macbeth",
                   help="built-in scene (macbeth, slanted_edge, frequency_sweep, zone_plate, star, dead_leaves, "
                        "point_array, grid_lines, checkerboard, uniform_d65) or a file (.mat, .exr, .png, .jpg, .tif)")
    p.add_argument("--size", type=int, default=256,
                   help=f"scene size in samples ({MIN_SIZE} to {MAX_SIZE}; default 256)")
    p.add_argument("--seed", type=int, default=0, help="seed of the sensor noise (default 0)")
    p.add_argument("--port", type=int, default=5006, help="port (default 5006)")
    p.add_argument("--address", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser tab")
    p.set_defaults(func=run)


def _check_listen(address: str, port: int) -> None:
    """The server can listen on ``address:port``: the address resolves to one of this machine's and the port is free
    (and permitted), else ValueError / OSError naming --address or --port (checked here: Bokeh's own errors name
    neither)."""
    import errno
    import socket

    try:
        infos = socket.getaddrinfo(address, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (OSError, UnicodeError) as err:
        raise ValueError(f"address: cannot listen on {address!r}: not an address or host name of this machine "
                         f"({getattr(err, 'strerror', None) or err})") from err
    for family, kind, proto, _, sockaddr in infos:
        with socket.socket(family, kind, proto) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server's (tornado's) socket
            try:
                sock.bind(sockaddr)
            except OSError as err:
                if err.errno in (errno.EADDRNOTAVAIL, errno.EAFNOSUPPORT):
                    raise ValueError(f"address: cannot listen on {address!r}: not an address of this machine "
                                     f"({err.strerror})") from err
                why = "in use" if err.errno == errno.EADDRINUSE else err.strerror
                raise ValueError(f"port: cannot listen on {address}:{port} ({why}); expected a free port, e.g. "
                                 f"--port 0 for any") from err


def _check_config(config: str) -> None:
    """A --config file is UTF-8 YAML holding a mapping (the library's message would name neither --config nor the
    file); a preset name, or a missing file, is left to the library (its message names config)."""
    from pathlib import Path

    from .._yaml import check_yaml_mapping

    if Path(config).is_file():
        check_yaml_mapping(config, "config", "a YAML mapping with sections (optics, sensor, isp, ...)")


def run(args) -> int:
    import sys
    from pathlib import Path

    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port: expected 0..65535, got {args.port}")
    if not MIN_SIZE <= args.size <= MAX_SIZE:
        raise ValueError(f"--size: expected {MIN_SIZE} to {MAX_SIZE} samples, got {args.size}")
    _check_config(args.config)
    from ..viewer.session import SCENES

    scene_file = args.scene not in SCENES
    if scene_file and not Path(args.scene).exists():
        raise FileNotFoundError(f"scene: {args.scene!r} is neither a built-in scene {list(SCENES)} nor a file")
    _check_listen(args.address, args.port)
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
    except (ValueError, OSError) as err:  # a message without the argument's name: the scene file's, else the config's
        message = str(err)
        if message.startswith(("config:", "scene:", "size:", "seed:", "port:", "address:", "--")):
            raise
        which = "scene" if scene_file and (args.scene in message or args.config not in message) else "config"
        raise ValueError(f"{which}: {message.removeprefix('path: ')}") from err
    return 0
