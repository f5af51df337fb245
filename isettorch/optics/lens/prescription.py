"""Lens prescriptions: Zemax OpticStudio sequential ``.zmx`` files and a plain YAML form.

Lengths are millimetres. A ``.zmx`` file in other lens units (``UNIT CM``, ``UNIT IN``, ``UNIT M``/``METER``) is
converted on reading: radii (``CURV`` is 1/length), thicknesses, semi-diameters, clear apertures and ``ENPD`` by
the unit L (10, 25.4 or 1000 mm), and the even-asphere coefficient a_k of r^(2k) (units length^(1-2k), so that
the sag is a length) by L^(1-2k).

Surface 0 is the object: at infinity (``DISZ INFINITY``, or a finite ``|DISZ| >=`` :data:`INFINITE_OBJECT_MM`,
1e9 mm: files write 1.0E+10 for infinity; reading such a distance as infinity changes the paraxial quantities by
about f/DISZ relative, < 1e-7 for f < 100 mm) or at a finite distance ``DISZ > 0`` (the conjugate the lens was
designed for, kept as :attr:`Prescription.object_distance_mm`: :class:`~isettorch.optics.lens.LensAnalysis` and the
lens report work there by default, as OpticStudio does; the surface list itself always starts at infinity). A
virtual object (``DISZ < 0``) or one on the first vertex (0) is refused. The last surface is the image and must be
flat (the analysis works on paraxial image planes). The stop is a surface strictly between them.

Surface types: ``STANDARD`` (sphere/conic) and ``EVENASPH`` (sag z = c r^2 / (1 + sqrt(1 - (1+k) c^2 r^2)) +
sum_i a_i r^(2i), Zemax ``PARM 1..8`` = a_1..a_8). Apertures: ``CLAP rmin rmax`` (circular) and ``FLAP 0 semi``
(floating: the semi-diameter) clip rays; ``DIAM`` alone does not (OpticStudio's semi-diameters only draw, they do
not vignette). System aperture: ``ENPD`` (entrance-pupil diameter), ``FLOA`` (float by stop size: the pupil whose
image is the stop's semi-diameter ``DIAM``, a **semi**-diameter in the file; optiland 0.6.3 reads it as a
diameter) or ``FNUM N 0`` (image-space F/#, OpticStudio's definition: paraxial EFL / paraxial EPD at the primary
wavelength, object at infinity, so EPD = EFL / N; resolved by ``LensAnalysis``).

Fields: angles (``FTYP 0``); object heights (``FTYP 1``, lens units; a finite object only), converted to the angle
theta = atan(h / (D + z_EP)) of the chief ray from the object point to the paraxial entrance pupil's centre, z_EP
from the first vertex (the analysis places a field's object point there); or paraxial (``FTYP 2``) or real
(``FTYP 3``) image heights in lens units, converted to the field angles that reach them on the paraxial image plane
of the file's object (:func:`field_angles_of_image_heights`); ``XFLN``/``YFLN`` (current dialect; the
number of fields is FTYP's third value) or ``XFLD``/``YFLD`` (older dialect, e.g. ``FTYP 0 0`` / ``XFLD 0 0 0`` /
``YFLD 0 5 10``: one value per field).
Wavelengths (um in the file): ``WAVM n value weight`` (current; the number in use is FTYP's fourth value: files
carry 24 ``WAVM`` slots) or ``WAVL v1 v2 ...`` (older). ``PWAV n`` is the primary wavelength (default 1); the
analysis reports paraxial data there, as OpticStudio does.

Glasses: catalogue names (``GCAT``; :mod:`isettorch.optics.lens.glass`) and model glasses ``GLAS ___BLANK 1 0 n_d
V_d ...`` (an index and Abbe number, as designs from patents give them: Buchdahl's model, see the glass module).

Refused with a :class:`PrescriptionError` naming the keyword: a truncated or non-numeric operand (``line 12:
CURV: expected a value``), non-sequential mode, surface types other than STANDARD and EVENASPH, mirrors,
decentred or non-circular apertures, object heights of an object at infinity, other field types (``FTYP`` 4,
...), object-space
telecentricity and afocal image space (``FTYP`` flags), nonzero vignetting factors (``VDXN VDYN VCXN VCYN VANN``:
OpticStudio would trace a vignetted pupil; zeros, as files usually write, are accepted), ``OBNA``, a curved image
surface, a negative thickness inside glass (a negative air gap is legitimate), and both dialects of the field or
wavelength lines in one file. Purely cosmetic or unrecognised operands are ignored.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import yaml

from ..._yaml import load_yaml
from .glass import model_glass_name, parse_model_glass

__all__ = ["Surface", "Prescription", "PrescriptionError", "read_zmx", "read_lens_yaml", "load_lens",
           "bundled_lenses", "INFINITE_OBJECT_MM", "LENS_UNITS_MM"]

DATA_DIR = Path(__file__).parent / "data"

#: An object surface thickness at least this large (mm) is read as an object at infinity.
INFINITE_OBJECT_MM = 1e9

#: Zemax ``UNIT`` lens units -> millimetres per unit.
LENS_UNITS_MM = {"MM": 1.0, "CM": 10.0, "IN": 25.4, "INCH": 25.4, "M": 1000.0, "METER": 1000.0}

#: Default primary wavelength (nm) for a lens that states none (the d line as 587.6 nm).
DEFAULT_PRIMARY_NM = 587.6


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
    """A rotationally symmetric sequential lens.

    Args:
        surfaces: object (its thickness infinite: the object distance is ``object_distance_mm``), the lens
            surfaces, image (flat; its position is used only with ``LensAnalysis(image_plane='prescription')``).
        entrance_pupil_diameter_mm: EPD, or None when ``float_by_stop`` or ``image_f_number`` gives the pupil.
        float_by_stop: the EPD is the stop's semi-diameter imaged into object space.
        image_f_number: image-space F/# (EPD = EFL / F/# at the primary wavelength).
        field_angles_deg: the file's field angles (radial, deg).
        wavelengths_nm, primary_wavelength_nm: the file's wavelengths; the paraxial data (EFL, F/#, pupils, the
            focus) are computed at the primary one.
        catalogs: GCAT catalogue names, in the file's order.
        object_distance_mm: the object distance the lens was designed for (mm, object plane to the first vertex:
            the file's object thickness; ``math.inf``, the default, for an object at infinity). The analysis and
            the lens report default to it; ``LensOptics`` focuses where its ``focus_distance_m`` says.
    """

    surfaces: list[Surface]
    entrance_pupil_diameter_mm: float | None = None
    float_by_stop: bool = False
    field_angles_deg: tuple[float, ...] = (0.0,)
    wavelengths_nm: tuple[float, ...] = (DEFAULT_PRIMARY_NM,)
    primary_wavelength_nm: float = DEFAULT_PRIMARY_NM
    catalogs: tuple[str, ...] = ("SCHOTT", "OHARA", "HOYA", "CDGM", "HIKARI", "SUMITA")
    name: str = ""
    source: str = ""
    image_f_number: float | None = None
    object_distance_mm: float = math.inf

    def __post_init__(self):
        lens = self.name or "lens"
        if len(self.surfaces) < 3:
            raise PrescriptionError(f"{lens}: surfaces: expected object, at least one lens surface and image, got "
                                    f"{len(self.surfaces)}")
        last = len(self.surfaces) - 1
        stops = [i for i, s in enumerate(self.surfaces) if s.is_stop]
        if len(stops) != 1:
            raise PrescriptionError(f"{lens}: expected exactly one stop surface, got {stops}")
        if not 0 < stops[0] < last:
            where = "object" if stops[0] == 0 else "image"
            raise PrescriptionError(f"{lens}: STOP on the {where} surface ({stops[0]}); the stop must be a lens "
                                    f"surface strictly between the object (0) and the image ({last})")
        if not math.isinf(self.surfaces[0].thickness_mm):
            raise PrescriptionError(f"{lens}: surface 0: the object surface's thickness is infinite (got "
                                    f"{self.surfaces[0].thickness_mm} mm); a finite object distance is "
                                    f"object_distance_mm")
        d = self.object_distance_mm
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not d > 0:
            raise PrescriptionError(f"{lens}: object_distance_mm: expected a distance > 0 mm (object plane to the "
                                    f"first vertex; math.inf for infinity), got {d!r}")
        if self.surfaces[last].curvature_per_mm != 0:
            raise PrescriptionError(f"{lens}: image surface {last}: curvature {self.surfaces[last].curvature_per_mm} "
                                    f"per mm (CURV); only a flat image surface is supported")
        apertures = [k for k, on in (("entrance_pupil_diameter_mm", self.entrance_pupil_diameter_mm is not None),
                                     ("float_by_stop", bool(self.float_by_stop)),
                                     ("image_f_number", self.image_f_number is not None)) if on]
        if not apertures:
            raise PrescriptionError(f"{lens}: no system aperture (ENPD, FLOA or FNUM; in YAML aperture: "
                                    f"entrance_pupil_diameter_mm, float_by_stop or image_f_number)")
        if len(apertures) > 1:
            raise PrescriptionError(f"{lens}: more than one system aperture {apertures}; expected one")
        for k in ("entrance_pupil_diameter_mm", "image_f_number"):
            v = getattr(self, k)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise PrescriptionError(f"{lens}: {k}: expected a finite value > 0, got {v}")
        if self.float_by_stop and not self.surfaces[stops[0]].semi_diameter_mm:
            raise PrescriptionError(f"{lens}: float-by-stop aperture but the stop surface {stops[0]} has no "
                                    f"semi-diameter")
        for i, s in enumerate(self.surfaces):
            if s.kind not in ("STANDARD", "EVENASPH"):
                raise PrescriptionError(f"{lens}: surface {i}: unsupported surface type {s.kind!r}; expected "
                                        f"STANDARD or EVENASPH")
            # the numbers of a lens surface (NaN gave a NaN focal length; a negative semi-diameter was taken)
            values = {"curvature_per_mm": s.curvature_per_mm, "conic": s.conic, "aperture_min_mm": s.aperture_min_mm,
                      **{f"aspheric[{k}]": a for k, a in enumerate(s.aspheric)}}
            if i > 0:
                values["thickness_mm"] = s.thickness_mm
            for key, v in values.items():
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise PrescriptionError(f"{lens}: surface {i}: {key}: expected a finite number, got {v!r}")
            for key in ("semi_diameter_mm", "aperture_mm"):
                v = getattr(s, key)
                if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                                      or not (math.isfinite(v) and v >= 0)):
                    raise PrescriptionError(f"{lens}: surface {i}: {key}: expected None or a finite number >= 0, "
                                            f"got {v!r}")
            if not isinstance(s.is_stop, bool):
                raise PrescriptionError(f"{lens}: surface {i}: is_stop: expected true or false, got {s.is_stop!r}")
            # a clear aperture's inner radius (CLAP rmin): negative made a central obstruction of |rmin| (the
            # tracer keeps rho^2 >= rmin^2), above the outer radius it blocked every ray without naming CLAP
            if s.aperture_min_mm < 0 or (s.aperture_mm is not None and s.aperture_min_mm > s.aperture_mm):
                raise PrescriptionError(f"{lens}: surface {i}: aperture_min_mm (CLAP's minimum radius): expected 0 <= "
                                        f"minimum <= maximum radius {s.aperture_mm!r}, got {s.aperture_min_mm!r}")
            if s.kind == "STANDARD" and any(a != 0 for a in s.aspheric):  # traced anyway, unlike the .zmx reader
                raise PrescriptionError(f"{lens}: surface {i}: aspheric: coefficients on a STANDARD surface; they "
                                        f"belong to an EVENASPH surface (set type EVENASPH, or drop them)")
            if 0 < i < last and s.thickness_mm < 0 and s.material is not None:
                raise PrescriptionError(f"{lens}: surface {i}: negative thickness {s.thickness_mm} mm inside glass "
                                        f"{s.material!r}; only air gaps may be negative")
        for name, vals in (("wavelengths_nm", self.wavelengths_nm), ("primary_wavelength_nm",
                                                                     (self.primary_wavelength_nm,))):
            if not vals or not all(math.isfinite(w) and w > 0 for w in vals):
                raise PrescriptionError(f"{lens}: {name}: expected finite wavelengths > 0 nm, got {vals}")
        if not self.field_angles_deg or not all(math.isfinite(f) and abs(f) < 90 for f in self.field_angles_deg):
            raise PrescriptionError(f"{lens}: field_angles_deg: expected one or more angles within (-90, 90) deg, "
                                    f"got {list(self.field_angles_deg)}")  # ([] failed later: max() of nothing)

    @property
    def stop_index(self) -> int:
        return next(i for i, s in enumerate(self.surfaces) if s.is_stop)

    @property
    def max_field_deg(self) -> float:
        return max(abs(f) for f in self.field_angles_deg)


def _num(tok: str, what: str) -> float:
    try:
        v = float(tok.replace(",", "."))
    except ValueError:
        if tok.upper() == "INFINITY":
            return math.inf
        raise PrescriptionError(f"{what}: expected a number, got {tok!r}") from None
    if math.isnan(v):
        raise PrescriptionError(f"{what}: expected a number, got {tok!r}")
    return v


def _int(tok: str, what: str) -> int:
    try:
        return int(tok)
    except ValueError:
        raise PrescriptionError(f"{what}: expected an integer, got {tok!r}") from None


def _decode(raw: bytes) -> str:
    """Zemax writes UTF-16 LE with a BOM (newer versions), older ones UTF-8/ANSI."""
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16")
    if raw.startswith(b"\xef\xbb\xbf"):
        return raw[3:].decode("utf-8")
    if len(raw) > 1 and raw[1:2] == b"\x00":  # UTF-16 LE without BOM
        return raw.decode("utf-16-le")
    if len(raw) > 1 and raw[0:1] == b"\x00":  # UTF-16 BE without BOM (read as 'no SURF blocks')
        return raw.decode("utf-16-be")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


_VIGNETTING = ("VDXN", "VDYN", "VCXN", "VCYN", "VANN")
_FIELD_LINES = {"XFLN": ("new", "x"), "YFLN": ("new", "y"), "XFLD": ("old", "x"), "YFLD": ("old", "y")}


def _all_zero(values) -> bool:
    """Whether every operand is a number equal to 0 (and there is at least one)."""
    try:
        return bool(values) and all(float(v) == 0.0 for v in values)
    except ValueError:
        return False


def read_zmx(path: str | Path) -> Prescription:
    """Read a sequential Zemax ``.zmx`` file (any of its encodings) into a :class:`Prescription`.

    What is read, converted and refused is listed in the module docstring; every refusal is a
    :class:`PrescriptionError` naming the file line and keyword.
    """
    path = Path(path)
    text = _decode(path.read_bytes())
    where = str(path)
    surfaces: list[Surface] = []
    cur: Surface | None = None
    parms: dict[int, dict[int, tuple[float, str]]] = {}  # surface -> PARM k -> (value, where)
    floating: dict[int, str] = {}  # surfaces with FLAP and no explicit semi-aperture
    surface_at: dict[int, str] = {}  # surface -> its SURF line
    field_type, field_type_at = 0, where  # FTYP's first value (FIELD_TYPES)
    disz_at: dict[int, str] = {}  # surfaces with a DISZ line
    apertures: dict[str, float | None] = {}
    fields: dict[tuple[str, str], list[float]] = {}
    vignetting: dict[str, tuple[list[float], str]] = {}
    wavm: dict[int, float] = {}
    wavl: list[float] | None = None
    line_at: dict[str, str] = {}
    pwav, pwav_at = 1, None
    nfields = nwaves = None
    unit = 1.0
    catalogs: tuple[str, ...] = ()
    name = path.stem
    for lineno, line in enumerate(text.splitlines(), 1):
        tok = line.split()
        if not tok:
            continue
        op = tok[0].upper()
        at = f"{where}: line {lineno}: {op}"

        def arg(i=1, what="a value", tok=tok, at=at):
            if len(tok) <= i:
                raise PrescriptionError(f"{at}: expected {what}")
            return tok[i]

        def val(i=1, what="a value", infinite_ok=False, tok=tok, at=at):
            v = _num(arg(i, what), at)
            if math.isinf(v) and not infinite_ok:
                raise PrescriptionError(f"{at}: expected a finite number, got {tok[i]!r}")
            return v

        def vals(what="one or more values", tok=tok, at=at):
            if len(tok) < 2:
                raise PrescriptionError(f"{at}: expected {what}")
            return [val(i) for i in range(1, len(tok))]

        if op == "MODE":
            if arg(1, "a mode (SEQ)").upper() != "SEQ":
                raise PrescriptionError(f"{at}: only sequential (MODE SEQ) files are supported, got {tok[1]!r}")
        elif op == "UNIT":
            u = arg(1, "the lens unit (MM, CM, IN or M)").upper()
            if u not in LENS_UNITS_MM:
                raise PrescriptionError(f"{at}: lens units {tok[1]!r}; expected one of {sorted(LENS_UNITS_MM)}")
            unit = LENS_UNITS_MM[u]
        elif op == "NAME" and len(tok) > 1:
            name = " ".join(line.split(None, 1)[1:]).strip()
        elif op == "ENPD":
            apertures[op] = val(1, "the entrance-pupil diameter")
        elif op == "FLOA":
            apertures[op] = None
        elif op == "FNUM":
            apertures[op] = val(1, "the F-number")
            if len(tok) > 2 and _int(tok[2], at) != 0:
                raise PrescriptionError(f"{at}: F-number type {tok[2]} is not supported; expected 0 (image-space "
                                        f"F/#)")
        elif op == "OBNA":
            raise PrescriptionError(f"{at}: system aperture type {op} (object-space NA) is not supported; "
                                    f"expected ENPD, FLOA or FNUM")
        elif op == "GCAT":
            arg(1, "one or more glass catalogue names")
            catalogs = tuple(t.upper() for t in tok[1:])
        elif op == "FTYP":
            ftype = _int(arg(1, "the field type"), at)
            if ftype not in FIELD_TYPES:
                raise PrescriptionError(f"{at}: field type {ftype}; expected angles (FTYP 0), object heights (1) or "
                                        f"image heights (2: paraxial, 3: real)")
            field_type, field_type_at = ftype, at
            # FTYP type telecentric nfields nwaves normalisation ? afocal (older files: FTYP type telecentric)
            flag = {i: _int(tok[i], at) for i in (2, 3, 4, 7) if i < len(tok)}
            if flag.get(2, 0) != 0:
                raise PrescriptionError(f"{at}: telecentric object space (second value {tok[2]}) is not "
                                        f"supported; expected 0")
            if flag.get(7, 0) != 0:
                raise PrescriptionError(f"{at}: afocal image space (eighth value {tok[7]}) is not supported; "
                                        f"expected 0")
            nfields, nwaves = flag.get(3), flag.get(4)
            for k, n in (("number of fields", nfields), ("number of wavelengths", nwaves)):
                if n is not None and n < 1:
                    raise PrescriptionError(f"{at}: {k} {n}; expected >= 1")
        elif op in _FIELD_LINES:
            fields[_FIELD_LINES[op]] = vals("one field angle per field")
            line_at[op] = at
        elif op in _VIGNETTING:
            vignetting[op] = (vals("one value per field"), at)
        elif op == "WAVM":
            slot = _int(arg(1, "the wavelength number and value (um)"), at)
            wavm[slot] = val(2, "the wavelength (um) after its number") * 1000.0
            line_at["WAVM"] = at
        elif op == "WAVL":
            wavl = [w * 1000.0 for w in vals("one wavelength (um) per wavelength")]
            line_at["WAVL"] = at
        elif op == "PWAV":
            pwav, pwav_at = _int(arg(1, "the primary wavelength's number"), at), at
        elif op == "SURF":
            cur = Surface()
            surfaces.append(cur)
            surface_at[len(surfaces) - 1] = at
        elif cur is not None:
            si = len(surfaces) - 1
            if op == "TYPE":
                cur.kind = arg(1, "a surface type").upper()
                if cur.kind not in ("STANDARD", "EVENASPH"):
                    raise PrescriptionError(f"{at}: surface {si} has unsupported type {tok[1]!r}; expected "
                                            f"STANDARD or EVENASPH")
            elif op == "CURV":
                cur.curvature_per_mm = val()
            elif op == "DISZ":
                cur.thickness_mm = val(infinite_ok=True)
                disz_at[si] = at
            elif op == "CONI":
                cur.conic = val()
            elif op == "PARM":
                k = _int(arg(1, "the parameter number and value"), at)
                parms.setdefault(si, {})[k] = (val(2, "the parameter value after its number"), at)
            elif op == "GLAS":
                g = arg(1, "a glass name")
                if g.upper() == "MIRROR":
                    raise PrescriptionError(f"{at}: mirrors are not supported (refractive lenses only)")
                if g.startswith("___BLANK"):
                    # a model glass, GLAS ___BLANK <solve type> <flag> n_d V_d [dPgF ...] (glass.py: Buchdahl's
                    # model of n_d and V_d)
                    nd, vd = val(4, "the model glass's n_d"), val(5, "the model glass's V_d after n_d")
                    g = model_glass_name(nd, vd)
                    try:
                        parse_model_glass(g)
                    except ValueError as err:
                        raise PrescriptionError(f"{at}: {err}") from err
                cur.material = None if g.upper() == "AIR" else g
            elif op == "DIAM":
                cur.semi_diameter_mm = val(1, "the semi-diameter")
            elif op == "STOP":
                cur.is_stop = True
            elif op == "CLAP":
                cur.aperture_min_mm = val(1, "the minimum and maximum radii")
                cur.aperture_mm = val(2, "the maximum radius after the minimum")
                floating.pop(si, None)
            elif op == "FLAP":
                semi = val(2, "the semi-aperture (FLAP 0 semi)") if len(tok) > 2 else 0.0
                if semi < 0:  # (was taken as a floating aperture: the DIAM value, without a word)
                    raise PrescriptionError(f"{at}: FLAP: expected a semi-aperture >= 0 (0: floating), got {semi}")
                cur.aperture_mm = semi
                if semi <= 0:
                    floating[si] = at
                else:
                    floating.pop(si, None)
            elif op in ("OBDC", "DECX", "DECY", "TILT") and _all_zero(tok[1:]):
                continue  # a zero decentre or tilt (files write OBDC 0 0 by default): nothing to model
            elif op in ("SQAP", "ELAP", "OBSC", "OBDC", "UDAP", "DECX", "DECY", "TILT"):
                raise PrescriptionError(f"{at}: surface {si}: operand {op} (non-circular or decentred "
                                        f"apertures/surfaces) is not supported")
    if not surfaces:
        raise PrescriptionError(f"{where}: no SURF blocks; expected a sequential Zemax lens file")
    # FLAP with an automatic semi-aperture: OpticStudio's floating aperture is the surface's semi-diameter
    for si, at in floating.items():
        s = surfaces[si]
        if not s.semi_diameter_mm or s.semi_diameter_mm <= 0:
            raise PrescriptionError(f"{at}: surface {si}: floating aperture without a semi-aperture and no "
                                    f"semi-diameter (DIAM) to take it from; expected FLAP 0 semi or a DIAM line")
        s.aperture_mm = s.semi_diameter_mm
    for si, ps in parms.items():  # PARM lines may come before or after TYPE: resolved here
        if surfaces[si].kind == "EVENASPH":
            for k, (v, at) in ps.items():
                if not 1 <= k <= 8:
                    if v != 0:
                        raise PrescriptionError(f"{at}: surface {si}: even-asphere parameter {k}; expected 1..8")
                    continue
                a = list(surfaces[si].aspheric) + [0.0] * max(0, k - len(surfaces[si].aspheric))
                a[k - 1] = v
                surfaces[si].aspheric = tuple(a)
    if len(apertures) > 1:
        raise PrescriptionError(f"{where}: more than one system aperture {sorted(apertures)}; expected one of "
                                f"ENPD, FLOA or FNUM")
    epd = apertures.get("ENPD")
    # --- lens units -> mm (lengths by L; curvature 1/L; even-asphere a_k of r^(2k) by L^(1 - 2k)) -------------
    if unit != 1.0:
        for s in surfaces:
            s.curvature_per_mm /= unit
            s.thickness_mm *= unit
            s.semi_diameter_mm = None if s.semi_diameter_mm is None else s.semi_diameter_mm * unit
            s.aperture_mm = None if s.aperture_mm is None else s.aperture_mm * unit
            s.aperture_min_mm *= unit
            s.aspheric = tuple(a * unit ** (1 - 2 * k) for k, a in enumerate(s.aspheric, 1))
        epd = None if epd is None else epd * unit
    for si, s in enumerate(surfaces[:-1]):
        if s.material is not None and si not in disz_at:  # (read as glass of thickness 0; the YAML reader refuses it)
            raise PrescriptionError(f"{surface_at[si]}: surface {si} is followed by glass ({s.material}) but has no "
                                    f"DISZ; expected its thickness (lens units to the next surface)")
    object_mm = surfaces[0].thickness_mm if surfaces else math.inf
    if abs(object_mm) >= INFINITE_OBJECT_MM:  # (INFINITY, or 1e10 as files write it)
        object_mm = math.inf  # changes paraxial data by ~ f / DISZ relative (module docstring)
    elif not object_mm > 0:
        raise PrescriptionError(f"{disz_at.get(0, surface_at.get(0, where))}: object distance (surface 0's DISZ) "
                                f"{object_mm / unit:g}; expected a real object: a distance > 0 lens units, or "
                                f"INFINITY (a virtual object or one on the first vertex is not supported)")
    if surfaces:
        surfaces[0].thickness_mm = math.inf
    # --- fields -------------------------------------------------------------------------------------------------
    dialects = {d for d, _ in fields}
    if len(dialects) > 1:
        raise PrescriptionError(f"{where}: both the XFLN/YFLN and the older XFLD/YFLD field lines are present "
                                f"({', '.join(sorted(line_at[k] for k in _FIELD_LINES if k in line_at))}); "
                                f"expected one dialect")
    xf = next((v for (d, ax), v in fields.items() if ax == "x"), [])
    yf = next((v for (d, ax), v in fields.items() if ax == "y"), [])
    if "old" in dialects and xf and yf and len(xf) != len(yf):
        raise PrescriptionError(f"{line_at.get('YFLD')}: {len(yf)} field values but XFLD has {len(xf)}; the "
                                f"number of fields is ambiguous")
    n = max(len(xf), len(yf))
    if nfields is not None and n:
        if n < nfields:
            raise PrescriptionError(f"{where}: FTYP declares {nfields} fields but the field lines hold {n}")
        n = nfields
    field_angles = tuple(math.hypot(xf[i] if i < len(xf) else 0.0, yf[i] if i < len(yf) else 0.0)
                         for i in range(n))
    for v, at in vignetting.values():
        bad = [x for x in v[: n or None] if x != 0]
        if bad:
            raise PrescriptionError(f"{at}: nonzero vignetting factors {v[: n or None]} are not supported (rays "
                                    f"fill the unvignetted entrance pupil; vignetting comes from the clear "
                                    f"apertures); expected zeros")
    # --- wavelengths --------------------------------------------------------------------------------------------
    if wavm and wavl is not None:
        raise PrescriptionError(f"{where}: both WAVM ({line_at['WAVM']}) and the older WAVL ({line_at['WAVL']}) "
                                f"wavelength lines are present; expected one dialect")
    if wavl is not None:
        wl = wavl
        if nwaves is not None:
            if len(wl) < nwaves:
                raise PrescriptionError(f"{line_at['WAVL']}: {len(wl)} wavelengths but FTYP declares {nwaves}")
            wl = wl[:nwaves]
    elif wavm:
        slots = range(1, (nwaves if nwaves is not None else max(wavm)) + 1)
        missing = [k for k in slots if k not in wavm]
        if missing:
            raise PrescriptionError(f"{line_at['WAVM']}: wavelength number(s) {missing} of {len(slots)} missing; "
                                    f"expected WAVM 1..{len(slots)}")
        wl = [wavm[k] for k in slots]
    else:
        wl = []
    if wl:
        if not 1 <= pwav <= len(wl):
            raise PrescriptionError(f"{pwav_at or where}: primary wavelength number {pwav} is not one of the "
                                    f"file's {len(wl)} wavelengths")
        primary = wl[pwav - 1]
    else:
        if pwav != 1:
            raise PrescriptionError(f"{pwav_at}: primary wavelength number {pwav} but the file has no "
                                    f"wavelengths (WAVM or WAVL)")
        wl, primary = [DEFAULT_PRIMARY_NM], DEFAULT_PRIMARY_NM
    bad = [w for w in wl if not (math.isfinite(w) and w > 0)]
    if bad:
        raise PrescriptionError(f"{where}: wavelengths {bad} nm; expected finite values > 0 (um in the file)")
    kw = {"catalogs": catalogs} if catalogs else {}
    heights = [v * unit for v in field_angles] if field_type else None  # object (FTYP 1) or image heights (mm)
    if field_type == 1 and math.isinf(object_mm):
        raise PrescriptionError(f"{field_type_at}: field type 1 (object heights) with the object at infinity; "
                                f"expected angles (FTYP 0) or image heights (2, 3), or a finite object distance")
    try:
        lens = Prescription(surfaces=surfaces, entrance_pupil_diameter_mm=epd, float_by_stop="FLOA" in apertures,
                            image_f_number=apertures.get("FNUM"),
                            field_angles_deg=(field_angles if heights is None else ()) or (0.0,),
                            wavelengths_nm=tuple(wl), primary_wavelength_nm=primary, name=name, source=str(path),
                            object_distance_mm=object_mm, **kw)
    except PrescriptionError as e:
        raise PrescriptionError(f"{where}: {e}") from None
    if heights:
        if field_type == 1:
            angles = field_angles_of_object_heights(lens, heights)
        else:
            angles = field_angles_of_image_heights(lens, heights, real=field_type == 3, where=field_type_at)
        lens = dataclasses.replace(lens, field_angles_deg=tuple(angles))
    return lens


#: Zemax field types read (FTYP's first value): 0 angles (deg), 1 object heights, 2 paraxial and 3 real image heights
#: (lens units)
FIELD_TYPES = (0, 1, 2, 3)


def field_angles_of_object_heights(lens: Prescription, heights_mm) -> list[float]:
    """The field angles (deg) of object points at ``heights_mm`` on the plane of the lens's finite object: theta =
    atan(h / (D + z_EP)), the chief ray's slope from the object point to the centre of the paraxial entrance pupil
    (primary wavelength; z_EP from the first vertex), where :meth:`LensAnalysis.rays` places a field's object
    point (Zemax ``FTYP 1``)."""
    from .analysis import LensAnalysis

    d = lens.object_distance_mm
    if math.isinf(d):
        raise PrescriptionError(f"{lens.name or 'lens'}: object heights need a finite object distance "
                                f"(object_distance_mm is infinite)")
    ep_z = float(LensAnalysis(lens).ref["ep_z"])
    if not d + ep_z > 0:
        raise PrescriptionError(f"{lens.name or 'lens'}: the entrance pupil ({ep_z:g} mm from the first vertex) "
                                f"lies at or before the object plane ({d:g} mm before it); object heights have no "
                                f"field angle")
    return [math.degrees(math.atan(abs(float(h)) / (d + ep_z))) for h in heights_mm]


def field_angles_of_image_heights(lens: Prescription, heights_mm, *, real: bool, where: str = "") -> list[float]:
    """The field angles (deg) whose chief rays reach the image ``heights_mm`` on the paraxial image plane of the
    primary wavelength, the object at the lens's ``object_distance_mm``: paraxial heights (Zemax ``FTYP 2``)
    ``y = h' tan(theta)``, h' the paraxial chief-ray height per tan(theta) on that plane (the effective focal length
    for an object at infinity); real heights (``FTYP 3``) by Newton's method on the traced chief ray's height, from
    the paraxial angle (the distortion makes them differ)."""
    import torch

    from .analysis import LensAnalysis

    a = LensAnalysis(lens)
    f = float(a.image_height_per_tan_mm())
    wl = lens.primary_wavelength_nm
    z0 = torch.zeros(1, dtype=a.dtype)
    image_z = a.image_plane_z(wl)

    def traced(theta: float) -> float:
        b = a.rays(theta, z0, z0, wl, clip=False)
        if not bool(b.valid.all()):
            raise PrescriptionError(f"{where}: the chief ray at {theta:.4g} deg misses a surface on the way to the "
                                    f"real image height asked for; the field is beyond the lens")
        return float(a.to_plane(b, image_z)[0][0, 1])

    out = []
    for h in heights_mm:
        h = abs(float(h))
        theta = math.degrees(math.atan(h / f))
        if not (h > 0 and real):
            out.append(theta)
            continue
        for _ in range(40):
            y = traced(theta)
            dt = 1e-5 * max(theta, 1.0)
            slope = (traced(theta + dt) - y) / dt
            if not slope > 0:
                raise PrescriptionError(f"{where}: the real image height stops growing with the field angle at "
                                        f"{theta:.4g} deg ({y:.6g} mm) before {h:g} mm")
            step = (h - y) / slope
            theta = min(theta + step, 89.0)
            if abs(step) < 1e-10 * max(theta, 1.0):
                break
        else:
            raise PrescriptionError(f"{where}: no field angle found whose real chief ray reaches {h:g} mm")
        out.append(theta)
    return out


_YAML_KEYS = ("name", "source", "aperture", "field_angles_deg", "wavelengths_nm", "primary_wavelength_nm", "catalogs",
              "object_distance_mm", "surfaces")
_YAML_SURFACE_KEYS = ("radius_mm", "curvature_per_mm", "thickness_mm", "material", "conic", "aspheric",
                      "semi_diameter_mm", "aperture_mm", "stop", "type")
_YAML_APERTURE_KEYS = ("entrance_pupil_diameter_mm", "float_by_stop", "image_f_number")


def _ynum(v, what: str) -> float:
    """A YAML number (PyYAML reads ``1e-5`` without a dot as a string: numeric strings are accepted)."""
    if not isinstance(v, bool) and isinstance(v, (int, float, str)):
        try:
            x = float(v)
        except ValueError:
            x = math.nan
        if not math.isnan(x):
            return x
    raise PrescriptionError(f"{what}: expected a number, got {v!r}")


def _ylist(v, what: str, item: str) -> list:
    if not isinstance(v, (list, tuple)):
        raise PrescriptionError(f"{what}: expected a list of {item}, got {v!r}")
    return list(v)


def _ymap(v, what: str, keys) -> dict:
    if not isinstance(v, dict):
        raise PrescriptionError(f"{what}: expected a mapping with keys from {list(keys)}, got {v!r}")
    bad = [k for k in v if k not in keys]
    if bad:
        raise PrescriptionError(f"{what}: unknown keys {bad}; expected keys from {list(keys)}")
    return v


def _ybool(v, what: str) -> bool:
    if not isinstance(v, bool):
        raise PrescriptionError(f"{what}: expected true or false, got {v!r}")
    return v


def read_lens_yaml(path_or_dict) -> Prescription:
    """Read a lens prescription in the plain YAML form (a file path or an already-parsed dict).

    The form (lengths in mm; the primary wavelength, one of ``wavelengths_nm``, defaults to the listed one nearest
    587.6 nm, the d line; ``material`` is a glass name, air when absent or ``air`` in any case, or a model glass
    ``"n_d/V_d"`` such as ``"1.5168/64.17"``)::

        name: Cooke triplet
        source: ...
        aperture: {entrance_pupil_diameter_mm: 10}      # or {float_by_stop: true} or {image_f_number: 5}
        field_angles_deg: [0, 14, 20]
        wavelengths_nm: [486.1, 587.6, 656.3]
        primary_wavelength_nm: 587.6
        catalogs: [SCHOTT]
        object_distance_mm: .inf   # the object the lens is designed for (mm to the first vertex; default .inf)
        surfaces:            # lens surfaces in order (the object surface and the flat image are implied)
          - {radius_mm: 22.01359, thickness_mm: 3.25896, material: N-SK16, semi_diameter_mm: 5}
          - {radius_mm: .inf, thickness_mm: 5, stop: true, semi_diameter_mm: 4}
          - {radius_mm: 20, conic: -1, aspheric: [0, 1e-5], thickness_mm: 40, aperture_mm: 6}

    A radius of 0 or ``.inf`` is a flat surface (OpticStudio's convention); a surface without ``radius_mm`` or
    ``curvature_per_mm`` is flat. ``thickness_mm`` (to the next surface) defaults to 0 after air and is required
    before glass. ``aspheric`` coefficients make the surface EVENASPH (an explicit STANDARD type refuses them).

    Raises:
        PrescriptionError: invalid YAML, or an entry of the wrong kind (the message names the file and entry).
    """
    if isinstance(path_or_dict, dict):
        d, where = path_or_dict, "lens config"
    else:
        where = str(path_or_dict)
        with open(path_or_dict, encoding="utf-8") as fh:
            try:
                d = load_yaml(fh.read())  # safe, YAML 1.2 floats (1e-3 is a number)
            except yaml.YAMLError as e:
                raise PrescriptionError(f"{where}: not valid YAML: {' '.join(str(e).split())}") from None
    if not isinstance(d, dict) or "surfaces" not in d:
        got = "a mapping without 'surfaces'" if isinstance(d, dict) else type(d).__name__
        raise PrescriptionError(f"{where}: expected a mapping with a 'surfaces' list, got {got}")
    _ymap(d, where, _YAML_KEYS)
    rows = _ylist(d["surfaces"], f"{where}: surfaces", "surface mappings")
    surfaces = [Surface(thickness_mm=math.inf)]
    for i, s in enumerate(rows, 1):
        at = f"{where}: surface {i}"
        _ymap(s, at, _YAML_SURFACE_KEYS)
        if "radius_mm" in s and "curvature_per_mm" in s:
            raise PrescriptionError(f"{at}: both radius_mm and curvature_per_mm; expected one")
        if "radius_mm" in s:
            r = _ynum(s["radius_mm"], f"{at}: radius_mm")
            c = 0.0 if math.isinf(r) or r == 0 else 1.0 / r
        else:
            c = _ynum(s.get("curvature_per_mm", 0.0), f"{at}: curvature_per_mm")
        asph = tuple(_ynum(a, f"{at}: aspheric[{k}]")
                     for k, a in enumerate(_ylist(s.get("aspheric", ()), f"{at}: aspheric", "coefficients")))
        mat = s.get("material")
        if mat is not None and not isinstance(mat, str):
            raise PrescriptionError(f"{at}: material: expected a glass name, got {mat!r}")
        if mat is not None and mat.upper() == "MIRROR":  # (as the .zmx reader: it read as a glass not found)
            raise PrescriptionError(f"{at}: material: mirrors are not supported (refractive lenses only)")
        if mat is not None and mat.upper() == "AIR":  # in any case, as the glass lookup and the .zmx reader
            mat = None
        kind = s.get("type", "EVENASPH" if asph else "STANDARD")
        if not isinstance(kind, str):
            raise PrescriptionError(f"{at}: type: expected STANDARD or EVENASPH, got {kind!r}")
        opt = {k: None if s.get(k) is None else _ynum(s[k], f"{at}: {k}")
               for k in ("semi_diameter_mm", "aperture_mm")}
        if mat is not None and "thickness_mm" not in s:  # (a glass of thickness 0, unsaid)
            raise PrescriptionError(f"{at}: thickness_mm: a surface followed by glass ({mat}) needs its thickness "
                                    f"(mm to the next surface)")
        t = _ynum(s.get("thickness_mm", 0.0), f"{at}: thickness_mm")
        surfaces.append(Surface(curvature_per_mm=c, thickness_mm=t,
                                material=mat,
                                conic=_ynum(s.get("conic", 0.0), f"{at}: conic"), aspheric=asph,
                                is_stop=_ybool(s.get("stop", False), f"{at}: stop"), kind=kind.upper(), **opt))
    surfaces.append(Surface())
    ap = _ymap(d.get("aperture", {}), f"{where}: aperture", _YAML_APERTURE_KEYS)
    kw = {}
    if "catalogs" in d:
        cats = _ylist(d["catalogs"], f"{where}: catalogs", "catalogue names")
        if not all(isinstance(c, str) for c in cats):
            raise PrescriptionError(f"{where}: catalogs: expected catalogue names, got {cats!r}")
        kw["catalogs"] = tuple(c.upper() for c in cats)
    wl = tuple(_ynum(w, f"{where}: wavelengths_nm[{k}]") for k, w in enumerate(
        _ylist(d.get("wavelengths_nm", (486.1, 587.6, 656.3)), f"{where}: wavelengths_nm", "wavelengths (nm)")))
    fields = tuple(_ynum(f, f"{where}: field_angles_deg[{k}]") for k, f in enumerate(
        _ylist(d.get("field_angles_deg", (0.0,)), f"{where}: field_angles_deg", "angles (deg)")))
    epd, fno = (None if ap.get(k) is None else _ynum(ap[k], f"{where}: aperture: {k}")
                for k in ("entrance_pupil_diameter_mm", "image_f_number"))
    name = str(d.get("name", where))
    if "object_distance_mm" in d:
        kw["object_distance_mm"] = _ynum(d["object_distance_mm"], f"{where}: object_distance_mm")
    if "primary_wavelength_nm" in d:
        primary = _ynum(d["primary_wavelength_nm"], f"{where}: primary_wavelength_nm")
        if primary not in wl:  # (OpticStudio's primary is one of the system's wavelengths)
            raise PrescriptionError(f"{where}: primary_wavelength_nm: expected one of wavelengths_nm {list(wl)}, got "
                                    f"{primary}")
    else:  # the d line where listed, else the listed wavelength nearest it (587.6 was used for a 550 nm-only lens:
        # its focus, EFL and distortion reference at a wavelength it does not list)
        primary = min(wl, key=lambda w: abs(w - DEFAULT_PRIMARY_NM)) if wl else DEFAULT_PRIMARY_NM
    try:
        return Prescription(surfaces=surfaces, entrance_pupil_diameter_mm=epd, image_f_number=fno,
                            float_by_stop=_ybool(ap.get("float_by_stop", False), f"{where}: aperture: float_by_stop"),
                            field_angles_deg=fields, wavelengths_nm=wl,
                            primary_wavelength_nm=primary,
                            name=name, source=str(d.get("source", "")), **kw)
    except PrescriptionError as e:
        raise PrescriptionError(str(e) if name == where else f"{where}: {e}") from None


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
