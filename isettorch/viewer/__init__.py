"""``isettorch view``: ISET's scene, optical image, sensor and processor windows in a browser (optional extra
``viewer``: ``pip install isettorch[viewer]``).

:class:`ViewerSession` holds the camera, scene and render and computes what each window shows with the
library's modules; :func:`serve` runs the Bokeh page (:mod:`isettorch.viewer.app`).
"""

from .session import ROI, SCENES, Settings, ViewerSession, resolve_config

__all__ = ["ROI", "SCENES", "Settings", "ViewerSession", "resolve_config", "serve"]


def serve(*args, **kwargs):
    """Serve the viewer (see :func:`isettorch.viewer.app.serve`); needs the ``viewer`` extra (Bokeh)."""
    try:
        import bokeh  # noqa: F401

        from .app import serve as _serve
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError("isettorch view needs Bokeh: pip install 'isettorch[viewer]'") from err
    return _serve(*args, **kwargs)
