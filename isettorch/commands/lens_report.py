"""``isettorch lens-report LENS``: paraxial data, distortion, relative illumination, chief-ray angle and
diffraction MTF of a lens prescription (``.zmx``, ``.yaml`` or a bundled lens name), with OpticStudio's default
conventions (see ``isettorch.optics.lens.analysis``).

``--json`` prints exactly one JSON object ``{effective_focal_length_mm, f_number, max_field_deg, image_plane (of the
MTF), rows: [...]}``;
otherwise a table, and plots (PSF grid, MTF against field, distortion, relative illumination) in ``--out``.
Without ``--wavelengths-nm`` the rows are at the prescription's own wavelengths. Out-of-range arguments are checked
by ``lens_report`` and named with their option (``isettorch.cli``).
"""

from __future__ import annotations

from pathlib import Path

from ._outputs import strict_json


def _floats(s: str, what: str) -> list[float]:
    try:  # an empty item is a lost value ('0,,1' dropped it), not nothing
        vals = [float(v) for v in s.split(",")] if s.strip() else []
    except ValueError:
        raise ValueError(f"{what}: expected comma-separated numbers, got {s!r}") from None
    if not vals:
        raise ValueError(f"{what}: expected at least one value, got {s!r}")
    return vals


def register(sub) -> None:
    p = sub.add_parser("lens-report", help="ray-trace a lens prescription: EFL, distortion, RI, CRA, MTF")
    from ..optics.lens import bundled_lenses

    p.add_argument("lens", help=f"a .zmx or .yaml lens file, or a bundled lens name ({', '.join(bundled_lenses())})")
    p.add_argument("--fields", default="0,0.7,1",
                   help="fractions in [0, 1] of the largest field angle (default 0,0.7,1)")
    p.add_argument("--wavelengths-nm", default=None,
                   help="wavelengths (nm, > 0; default: the prescription's wavelengths)")
    p.add_argument("--frequencies-cy-mm", default="20,40,80",
                   help="MTF frequencies (cycles/mm, >= 0; default 20,40,80)")
    p.add_argument("--pupil-samples", type=int, default=128,
                   help="pupil grid for the FFT MTF, 16 to 1024 (fewer samples across the pupil do not give a "
                        "meaningful MTF; default 128, refined automatically for steep wavefronts)")
    p.add_argument("--image-plane", default="paraxial", choices=("paraxial", "prescription"),
                   help="the sensor plane of the MTF: the primary wavelength's paraxial focus (default) or the "
                        "file's image surface (where its designer focused it, as OpticStudio evaluates it)")
    p.add_argument("--json", action="store_true", help="print the JSON object only")
    p.add_argument("--out", default="lens_report", help="folder for the plots (without --json; default lens_report)")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..optics.lens import LensAnalysis, lens_report

    fields = _floats(args.fields, "--fields")
    waves = None if args.wavelengths_nm is None else _floats(args.wavelengths_nm, "--wavelengths-nm")
    freqs = _floats(args.frequencies_cy_mm, "--frequencies-cy-mm")
    # PrescriptionError, GlassError and TraceError are ValueErrors: one line and exit code 2 (isettorch.cli); the
    # range checks are lens_report's, whose messages start with the parameter name (shown as the option)
    if not args.json:  # the plots' folder, before the table is printed
        from ._outputs import check_dir

        check_dir(args.out, "out")
    try:
        analysis = LensAnalysis(args.lens, image_plane=args.image_plane)
    except UnicodeDecodeError as err:  # a binary or non-UTF-8 file: name it, not the codec
        raise ValueError(f"lens: {args.lens}: not UTF-8 text ({err.reason} at byte {err.start})") from err
    from ..optics.lens.glass import GlassError

    try:
        report = lens_report(analysis, fields, waves, freqs, pupil_samples=args.pupil_samples)
    except GlassError as err:  # outside a glass's range: the wavelengths asked for (the file's own are checked)
        if waves is None:
            raise
        raise ValueError(f"--wavelengths-nm: {err}") from err
    waves = list(dict.fromkeys(r["wavelength_nm"] for r in report["rows"]))  # the wavelengths reported
    if args.json:
        print(strict_json(report))
        return 0
    print(f"{analysis.prescription.name}: EFL {report['effective_focal_length_mm']:.4f} mm, "
          f"f/{report['f_number']:.4f}, max field {report['max_field_deg']:.3f} deg")
    shift = float(analysis.sensor_z - analysis.image_plane_z(analysis.reference_wavelength_nm))
    print(f"MTF on the {analysis.image_plane} image plane ({shift:+.4f} mm from the primary wavelength's paraxial "
          f"focus); image heights and distortion on each wavelength's paraxial focus")
    print(f"{'field':>6} {'wl nm':>7} {'y mm':>9} {'dist %':>8} {'RI':>6} {'RIflux':>6} {'CRA':>7}  MTF T / S at "
          f"{freqs} cy/mm")
    for r in report["rows"]:
        mt = " ".join(f"{v:.3f}" for v in r["mtf_tangential"])
        ms = " ".join(f"{v:.3f}" for v in r["mtf_sagittal"])
        print(f"{r['field']:6.3f} {r['wavelength_nm']:7.1f} {r['image_height_mm']:9.4f} "
              f"{r['distortion_percent']:8.4f} {r['relative_illumination']:6.3f} "
              f"{r['relative_illumination_flux']:6.3f} {r['chief_ray_angle_deg']:7.3f}  "
              f"{mt} / {ms}")
    _plots(analysis, report, fields, waves, freqs, Path(args.out))
    print(f"plots written to {args.out}/")
    return 0


def _plots(analysis, report, fields, waves, freqs, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    import torch

    out.mkdir(parents=True, exist_ok=True)
    rows = report["rows"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for wl in waves:
        rs = [r for r in rows if r["wavelength_nm"] == wl]
        f = [r["field"] for r in rs]
        axes[0].plot(f, [r["distortion_percent"] for r in rs], "o-", label=f"{wl:g} nm")
        line, = axes[1].plot(f, [r["relative_illumination_flux"] for r in rs], "o-", label=f"{wl:g} nm")
        axes[1].plot(f, [r["relative_illumination"] for r in rs], "x:", color=line.get_color())
        for k, nu in enumerate(freqs):
            axes[2].plot(f, [r["mtf_tangential"][k] for r in rs], "-", label=f"T {nu:g} cy/mm, {wl:g} nm")
            axes[2].plot(f, [r["mtf_sagittal"][k] for r in rs], "--")
    for ax, t in zip(axes, ("distortion (%)", "relative illumination (flux o, Rimmer x)",
                            "MTF (T solid, S dashed)")):
        ax.set_xlabel("field (fraction)")
        ax.set_title(t)
    axes[0].legend()
    axes[2].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out / "distortion_ri_mtf.png", dpi=120)
    plt.close(fig)
    from ..optics.lens.psf import otf_sampler, psf_on_grid

    # lambda N / 2 at the primary wavelength: Nyquist for the PSF
    pitch_mm = 0.5e-6 * analysis.f_number.abs().item() * analysis.reference_wavelength_nm
    size = 97
    half_um = size // 2 * pitch_mm * 1e3
    fig, axes = plt.subplots(len(waves), len(fields), figsize=(3 * len(fields), 3 * len(waves)), squeeze=False)
    with torch.no_grad():
        for i, wl in enumerate(waves):
            for j, f in enumerate(fields):
                psf = psf_on_grid(otf_sampler(analysis, f, wl, 64), torch.zeros(1, dtype=torch.float64), pitch_mm,
                                  size)[0]
                axes[i, j].imshow(np.sqrt(psf.numpy()), cmap="gray", origin="lower",
                                  extent=(-half_um, half_um, -half_um, half_um))
                axes[i, j].set_title(f"field {f:g}, {wl:g} nm (sqrt)", fontsize=8)
                axes[i, j].set_xlabel("x (um)", fontsize=7)
                axes[i, j].set_ylabel("y, field direction (um)", fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "psf_grid.png", dpi=120)
    plt.close(fig)
