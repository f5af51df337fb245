"""Lens prescriptions: Zemax OpticStudio sequential ``.zmx`` files and a plain YAML form.

Units are millimetres (``UNIT MM``; other units are rejected). Surface 0 is the object (at infinity), the last
surface the image. Supported surface types: ``STANDARD`` (sphere/conic) and ``EVENASPH``
(sag z = c r^2 / (1 + sqrt(1 - (1+k) c^2 r^2)) + sum_i a_i r^(2i), Zemax ``PARM 1..8`` = a_1..a_8).
Apertures: ``CLAP rmin rmax`` (circular) and ``FLAP 0 semi`` (floating: the semi-diameter) clip rays;
``DIAM`` alone does not (OpticStudio's semi-diameters only draw, they do not vignette).
System aperture: ``ENPD`` (entrance-pupil diameter) or ``FLOA`` (float by stop size: the pupil whose image is
the stop's semi-diameter ``DIAM``, a **semi**-diameter in the file — optiland 0.6.3 reads it as a diameter).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import yaml

__all__ = ["Surface", "Prescription", "PrescriptionError", "read_zmx", "read_lens_yaml", "load_lens",
           "bundled_lenses"]

DATA_DIR = Path(__file__).parent / "data"


class PrescriptionError(ValueError):
    """A prescription the reader cannot represent (names the file, surface and operand)."""


@dataclasses.dataclass
class Surface:
    curvature_per_mm: float = 0.0
    thickness_mm: float = 0.0          # to the next surface
    material: str | None = None        # glass after the surface (None = air)
    conic: float = 0.0
    aspheric: tuple[float, ...] = ()   # a_1.. for r^2, r^4, ...
    semi_diameter_mm: float | None = None
    aperture_mm: float | None = None   # clear (clipping) semi-aperture, or None
    aperture_min_mm: float = 0.0
    is_stop: bool = False
    kind: str = "STANDARD"


@dataclasses.dataclass
class Prescription:
    """A rotationally symmetric sequential lens, object at infinity.

    Args:
        surfaces: object, the lens surfaces, image (the image surface's position is not used by the
            analysis, which works on paraxial image planes).
        entrance_pupil_diameter_mm: EPD, or None when ``float_by_stop`` (then derived from the stop).
        field_angles_deg: the file's field angles (radial, deg).
        wavelengths_nm, primary_wavelength_nm: the file's wavelengths.
        catalogs: GCAT catalogue names, in the file's order.
    """

    surfaces: list[Surface]
    entrance_pupil_diameter_mm: float | None = None
    float_by_stop: bool = False
    field_angles_deg: tuple[float, ...] = (0.0,)
    wavelengths_nm: tuple[float, ...] = (587.6,)
    primary_wavelength_nm: float = 587.6
    catalogs: tuple[str, ...] = ("SCHOTT", "OHARA", "HOYA", "CDGM", "HIKARI", "SUMITA")
    name: str = ""
    source: str = ""

    def __post_init__(self):
        if len(self.surfaces) < 3:
            raise PrescriptionError(f"surfaces: expected object, at least one lens surface and image, got "
                                    f"{len(self.surfaces)}")
        stops = [i for i, s in enumerate(self.surfaces) if s.is_stop]
        if len(stops) != 1:
            raise PrescriptionError(f"{self.name or 'lens'}: expected exactly one stop surface, got {stops}")
        if not math.isinf(self.surfaces[0].thickness_mm):
            raise PrescriptionError(f"{self.name or 'lens'}: only objects at infinity are supported (object "
                                    f"thickness {self.surfaces[0].thickness_mm})")
        if self.entrance_pupil_diameter_mm is None and not self.float_by_stop:
            raise PrescriptionError(f"{self.name or 'lens'}: no system aperture (ENPD or FLOA)")
        if self.float_by_stop and not self.surfaces[stops[0]].semi_diameter_mm:
            raise PrescriptionError(f"{self.name or 'lens'}: float-by-stop aperture but the stop surface "
                                    f"{stops[0]} has no semi-diameter")
        if self.entrance_pupil_diameter_mm is not None and not self.entrance_pupil_diameter_mm > 0:
            raise PrescriptionError(f"entrance_pupil_diameter_mm: expected > 0, got "
                                    f"{self.entrance_pupil_diameter_mm}")
        for i, s in enumerate(self.surfaces):
            if s.kind not in ("STANDARD", "EVENASPH"):
                raise PrescriptionError(f"surface {i}: unsupported surface type {s.kind!r}; expected "
                                        f"STANDARD or EVENASPH")

    @property
    def stop_index(self) -> int:
        return next(i for i, s in enumerate(self.surfaces) if s.is_stop)

    @property
    def max_field_deg(self) -> float:
        return max(abs(f) for f in self.field_angles_deg)


def _num(tok: str, what: str) -> float:
    try:
        return float(tok.replace(",", "."))
    except ValueError:
        if tok.upper() == "INFINITY":
            return math.inf
        raise PrescriptionError(f"{what}: expected a number, got {tok!r}") from None


def _decode(raw: bytes) -> str:
    """Zemax writes UTF-16 LE with a BOM (newer versions), older ones UTF-8/ANSI."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16")
    if raw.startswith(b"\xef\xbb\xbf"):
        return raw[3:].decode("utf-8")
    if len(raw) > 1 and raw[1:2] == b"\x00":  # UTF-16 LE without BOM
        return raw.decode("utf-16-le")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


_IGNORED = {"VERS", "MODE", "NOTE", "PFIL", "LANG", "UNIT", "ENVD", "GFAC", "RAIM", "PUSH", "SDMA", "FTYP",
            "ROPD", "PICB", "XFLN", "YFLN", "FWGN", "VDXN", "VDYN", "VCXN", "VCYN", "VANN", "WWGT", "COMM", "CURV",
            "DISZ", "GLAS", "DIAM", "CONI", "PARM", "STOP", "SURF", "TYPE", "ENPD", "FLOA", "GCAT", "CLAP", "FLAP",
            "WAVM", "PWAV", "NAME"}


def read_zmx(path: str | Path) -> Prescription:
    """Read a sequential Zemax ``.zmx`` file (any of its encodings) into a :class:`Prescription`.

    Unsupported content that changes the optics (non-sequential mode, surface types other than STANDARD and
    EVENASPH, mirrors, field types other than angles, finite objects, non-mm units, model glasses) raises
    :class:`PrescriptionError` naming it; purely cosmetic operands are ignored.
    """
    path = Path(path)
    text = _decode(path.read_bytes())
    where = str(path)
    surfaces: list[Surface] = []
    cur: Surface | None = None
    epd = None
    floa = False
    xf: list[float] = []
    yf: list[float] = []
    waves: dict[int, float] = {}
    pwav = 1
    nfields = None
    catalogs: tuple[str, ...] = ()
    name = path.stem
    for lineno, line in enumerate(text.splitlines(), 1):
        tok = line.split()
        if not tok:
            continue
        op = tok[0].upper()
        at = f"{where}:{lineno} ({op})"
        if op == "MODE" and len(tok) > 1 and tok[1].upper() != "SEQ":
            raise PrescriptionError(f"{at}: only sequential (MODE SEQ) files are supported, got {tok[1]!r}")
        elif op == "UNIT" and len(tok) > 1 and tok[1].upper() != "MM":
            raise PrescriptionError(f"{at}: lens units {tok[1]!r}; expected MM")
        elif op == "NAME" and len(tok) > 1:
            name = " ".join(tok[1:])
        elif op == "ENPD":
            epd = _num(tok[1], at)
        elif op == "FLOA":
            floa = True
        elif op in ("FNUM", "OBNA", "OBSC"):
            raise PrescriptionError(f"{at}: system aperture type {op} is not supported; expected ENPD or FLOA")
        elif op == "GCAT":
            catalogs = tuple(t.upper() for t in tok[1:])
        elif op == "FTYP":
            if len(tok) > 1 and int(tok[1]) != 0:
                raise PrescriptionError(f"{at}: field type {tok[1]}; only angles (FTYP 0) are supported")
            if len(tok) > 3:
                nfields = int(tok[3])
        elif op == "XFLN":
            xf = [_num(t, at) for t in tok[1:]]
        elif op == "YFLN":
            yf = [_num(t, at) for t in tok[1:]]
        elif op == "WAVM" and len(tok) >= 3:
            waves[int(tok[1])] = _num(tok[2], at) * 1000.0
        elif op == "PWAV":
            pwav = int(tok[1])
        elif op == "SURF":
            cur = Surface()
            surfaces.append(cur)
        elif cur is not None:
            if op == "TYPE":
                cur.kind = tok[1].upper()
                if cur.kind not in ("STANDARD", "EVENASPH"):
                    raise PrescriptionError(f"{at}: surface {len(surfaces) - 1} has unsupported type {tok[1]!r}; "
                                            f"expected STANDARD or EVENASPH")
            elif op == "CURV":
                cur.curvature_per_mm = _num(tok[1], at)
            elif op == "DISZ":
                cur.thickness_mm = _num(tok[1], at)
            elif op == "CONI":
                cur.conic = _num(tok[1], at)
            elif op == "PARM":
                k = int(tok[1])
                v = _num(tok[2], at)
                if cur.kind == "EVENASPH" and 1 <= k <= 8:
                    a = list(cur.aspheric) + [0.0] * max(0, k - len(cur.aspheric))
                    a[k - 1] = v
                    cur.aspheric = tuple(a)
            elif op == "GLAS":
                g = tok[1]
                if g.upper() == "MIRROR":
                    raise PrescriptionError(f"{at}: mirrors are not supported (refractive lenses only)")
                if g.startswith("___BLANK"):
                    raise PrescriptionError(f"{at}: model glass {g!r} (index/Abbe solve) is not supported; "
                                            f"expected a catalogue glass name")
                cur.material = None if g.upper() == "AIR" else g
            elif op == "DIAM":
                cur.semi_diameter_mm = _num(tok[1], at)
            elif op == "STOP":
                cur.is_stop = True
            elif op == "CLAP":
                cur.aperture_min_mm, cur.aperture_mm = _num(tok[1], at), _num(tok[2], at)
            elif op == "FLAP":
                cur.aperture_mm = _num(tok[2], at) if len(tok) > 2 else cur.semi_diameter_mm
            elif op in ("SQAP", "ELAP", "OBSC", "OBDC", "UDAP", "DECX", "DECY", "TILT"):
                raise PrescriptionError(f"{at}: surface {len(surfaces) - 1}: operand {op} (non-circular or "
                                        f"decentred apertures/surfaces) is not supported")
    if not surfaces:
        raise PrescriptionError(f"{where}: no SURF blocks; expected a sequential Zemax lens file")
    for s in surfaces:
        if s.aperture_mm is not None and s.aperture_mm <= 0 and s.semi_diameter_mm:
            s.aperture_mm = s.semi_diameter_mm  # FLAP with an automatic semi-diameter
    fields = []
    n = max(len(xf), len(yf))
    if nfields is not None and n:
        n = min(n, nfields)
    for i in range(n):
        x = xf[i] if i < len(xf) else 0.0
        y = yf[i] if i < len(yf) else 0.0
        fields.append(math.hypot(x, y))
    wl = tuple(waves[k] for k in sorted(waves)) or (587.6,)
    primary = waves.get(pwav, wl[0])
    kw = {"catalogs": catalogs} if catalogs else {}
    return Prescription(surfaces=surfaces, entrance_pupil_diameter_mm=None if floa else epd, float_by_stop=floa,
                        field_angles_deg=tuple(fields) or (0.0,), wavelengths_nm=wl, primary_wavelength_nm=primary,
                        name=name, source=str(path), **kw)


def read_lens_yaml(path_or_dict) -> Prescription:
    """Read a lens prescription in the plain YAML form (a file path or an already-parsed dict).

    The form::

        name: Cooke triplet
        source: ...
        aperture: {entrance_pupil_diameter_mm: 10}      # or {float_by_stop: true}
        field_angles_deg: [0, 14, 20]
        wavelengths_nm: [486.1, 587.6, 656.3]
        catalogs: [SCHOTT]
        surfaces:            # lens surfaces in order (object at infinity and the image are implied)
          - {radius_mm: 22.01359, thickness_mm: 3.25896, material: N-SK16, semi_diameter_mm: 5}
          - {radius_mm: inf, thickness_mm: 5, stop: true, semi_diameter_mm: 4}
          - {radius_mm: 20, conic: -1, aspheric: [0, 1e-5], thickness_mm: 40, aperture_mm: 6}
    """
    if isinstance(path_or_dict, dict):
        d, where = path_or_dict, "lens config"
    else:
        where = str(path_or_dict)
        with open(path_or_dict, encoding="utf-8") as fh:
            d = yaml.safe_load(fh)
    if not isinstance(d, dict) or not isinstance(d.get("surfaces"), list):
        raise PrescriptionError(f"{where}: expected a mapping with a 'surfaces' list")
    allowed = {"radius_mm", "curvature_per_mm", "thickness_mm", "material", "conic", "aspheric",
               "semi_diameter_mm", "aperture_mm", "stop", "type"}
    surfaces = [Surface(thickness_mm=math.inf)]
    for i, s in enumerate(d["surfaces"], 1):
        bad = set(s) - allowed
        if bad:
            raise PrescriptionError(f"{where}: surface {i}: unknown keys {sorted(bad)}; expected {sorted(allowed)}")
        if "radius_mm" in s:
            r = float(s["radius_mm"])
            c = 0.0 if math.isinf(r) or r == 0 else 1.0 / r
        else:
            c = float(s.get("curvature_per_mm", 0.0))
        asph = tuple(float(a) for a in s.get("aspheric", ()))
        mat = s.get("material")
        surfaces.append(Surface(curvature_per_mm=c, thickness_mm=float(s.get("thickness_mm", 0.0)),
                                material=None if mat in (None, "AIR", "air") else str(mat),
                                conic=float(s.get("conic", 0.0)), aspheric=asph,
                                semi_diameter_mm=s.get("semi_diameter_mm"), aperture_mm=s.get("aperture_mm"),
                                is_stop=bool(s.get("stop", False)),
                                kind=str(s.get("type", "EVENASPH" if asph else "STANDARD")).upper()))
    surfaces.append(Surface())
    ap = d.get("aperture", {})
    kw = {}
    if "catalogs" in d:
        kw["catalogs"] = tuple(str(c).upper() for c in d["catalogs"])
    wl = tuple(float(w) for w in d.get("wavelengths_nm", (486.1, 587.6, 656.3)))
    return Prescription(surfaces=surfaces, entrance_pupil_diameter_mm=ap.get("entrance_pupil_diameter_mm"),
                        float_by_stop=bool(ap.get("float_by_stop", False)),
                        field_angles_deg=tuple(float(f) for f in d.get("field_angles_deg", (0.0,))),
                        wavelengths_nm=wl, primary_wavelength_nm=float(d.get("primary_wavelength_nm", 587.6)),
                        name=str(d.get("name", where)), source=str(d.get("source", "")), **kw)


def bundled_lenses() -> list[str]:
    """Names of the example lenses shipped with the package (``load_lens(name)``)."""
    return sorted(p.stem for p in DATA_DIR.glob("*") if p.suffix in (".zmx", ".yaml"))


def load_lens(lens) -> Prescription:
    """A :class:`Prescription` from a path (``.zmx``/``.yaml``), a bundled lens name, a dict or a Prescription."""
    if isinstance(lens, Prescription):
        return lens
    if isinstance(lens, dict):
        return read_lens_yaml(lens)
    p = Path(lens)
    if not p.exists():
        for ext in (".zmx", ".yaml"):
            q = DATA_DIR / (str(lens) + ext)
            if q.exists():
                p = q
                break
        else:
            raise FileNotFoundError(f"lens: {lens!r} is neither a file nor a bundled lens {bundled_lenses()}")
    if p.suffix.lower() == ".zmx":
        return read_zmx(p)
    if p.suffix.lower() in (".yaml", ".yml"):
        return read_lens_yaml(p)
    raise PrescriptionError(f"lens: {str(p)!r}: expected a .zmx or .yaml file")
