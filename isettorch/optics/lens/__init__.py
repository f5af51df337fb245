"""Ray-traced lenses: prescriptions (.zmx / YAML), a torch real-ray tracer, lens analysis and lens optics."""

from .analysis import LensAnalysis, lens_report
from .glass import GlassError, refractive_index
from .prescription import Prescription, PrescriptionError, Surface, bundled_lenses, load_lens, read_lens_yaml, read_zmx
from .trace import LensGeometry, TraceError

__all__ = ["LensAnalysis", "lens_report", "GlassError", "refractive_index", "Prescription", "PrescriptionError",
           "Surface", "bundled_lenses", "load_lens", "read_lens_yaml", "read_zmx", "LensGeometry", "TraceError"]
