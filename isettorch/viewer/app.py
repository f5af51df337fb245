"""The ``isettorch view`` page: a Bokeh server document with ISET's four windows side by side.

Each window shows its image; drag a box on it (box-select) to choose its region of interest. Under the images:
scene spectral radiance, optical-image spectral irradiance with the optics' PSF and MTF, the raw pixel
histogram with per-channel SNR, and the processed image's chromaticity with CIEDE2000 for the Macbeth chart.
The controls rebuild the camera from its config with the changed keys and re-render. All numbers come from
:class:`~isettorch.viewer.session.ViewerSession` (the library's modules); this file only draws them.

Bokeh (not Dash or Gradio) because its server keeps one Python session per browser tab next to the tensors,
pushes only the data that changed over a websocket (binary arrays, no re-serialised figures), has box-select
and image glyphs built in, and ships BokehJS inside the wheel, so the page works with no network.
"""

from __future__ import annotations

import time

import numpy as np

from .session import CFAS, EXPOSURES_MS, F_NUMBERS, PIXEL_SIZES_UM, ROI, SCENES, WINDOWS, ViewerSession

__all__ = ["make_document", "make_server", "serve"]

TITLES = {"scene": "Scene", "oi": "Optical image", "sensor": "Sensor", "ip": "Image processor"}
CHANNEL_COLOURS = {"R": "#d62728", "G": "#2ca02c", "B": "#1f77b4", "W": "#7f7f7f", "C": "#17becf",
                   "M": "#e377c2", "Y": "#bcbd22", "E": "#006400", "I": "#8c564b"}
MTF_COLOURS = {450.0: "#1f77b4", 550.0: "#2ca02c", 650.0: "#d62728"}
IMAGE_PX = 300  # on-screen width of each window's image


def _rgba(img: np.ndarray) -> np.ndarray:
    """[H, W, 3] in [0, 1] -> Bokeh's packed RGBA [H, W] uint32, flipped so row 0 is at the top."""
    h, w, _ = img.shape
    a = np.empty((h, w, 4), dtype=np.uint8)
    a[..., :3] = np.round(img * 255).astype(np.uint8)
    a[..., 3] = 255
    return np.flipud(a).copy().view(np.uint32).reshape(h, w)


def make_document(doc, session_factory) -> None:
    """Fill a Bokeh ``doc`` with the viewer for a fresh :class:`ViewerSession` from ``session_factory()``."""
    from bokeh.events import SelectionGeometry
    from bokeh.layouts import column, row
    from bokeh.models import (
        BoxSelectTool,
        ColumnDataSource,
        DataTable,
        Div,
        LinearColorMapper,
        NumberFormatter,
        RadioButtonGroup,
        Range1d,
        Select,
        Span,
        TableColumn,
        Toggle,
    )
    from bokeh.plotting import figure

    s: ViewerSession = session_factory()
    rois: dict[str, ROI] = {}
    sources = {w: ColumnDataSource(name=f"{w}_image", data={"image": [], "x": [], "y": [], "dw": [], "dh": []})
               for w in WINDOWS}
    boxes = {w: ColumnDataSource(name=f"{w}_roi", data={"row0": [], "row1": [], "col0": [], "col1": [],
                                                         "left": [], "right": [], "top": [], "bottom": []})
             for w in WINDOWS}
    status = ColumnDataSource(name="status", data={"renders": [0], "camera_s": [0.0], "update_s": [0.0]})
    status_div = Div(name="status_text", text="")

    # --- image windows ---------------------------------------------------------------
    figs = {}
    for w in WINDOWS:
        f = figure(name=f"{w}_figure", width=IMAGE_PX, height=IMAGE_PX, toolbar_location=None, min_border=0,
                   x_axis_location=None, y_axis_location=None,
                   x_range=Range1d(0, 1), y_range=Range1d(0, 1), css_classes=[f"isettorch-{w}"])
        f.grid.visible = False
        f.outline_line_color = None
        f.image_rgba(image="image", x="x", y="y", dw="dw", dh="dh", source=sources[w])
        f.quad(left="left", right="right", top="top", bottom="bottom", source=boxes[w], fill_alpha=0.0,
               line_color="yellow", line_width=2)
        box = BoxSelectTool(persistent=False)
        f.add_tools(box)
        f.toolbar.active_drag = box
        figs[w] = f

    # --- analysis plots ----------------------------------------------------------------
    scene_spec = ColumnDataSource(name="scene_spectrum", data={"wavelength_nm": [], "photons": []})
    oi_spec = ColumnDataSource(name="oi_spectrum", data={"wavelength_nm": [], "photons": []})
    p_scene = figure(name="scene_spectrum_plot", width=IMAGE_PX, height=220, title="ROI spectral radiance",
                     x_axis_label="wavelength (nm)", y_axis_label="photons/s/sr/m²/nm", toolbar_location=None)
    p_scene.line("wavelength_nm", "photons", source=scene_spec, line_width=2)
    p_oi = figure(name="oi_spectrum_plot", width=IMAGE_PX, height=220, title="ROI spectral irradiance",
                  x_axis_label="wavelength (nm)", y_axis_label="photons/s/m²/nm", toolbar_location=None)
    p_oi.line("wavelength_nm", "photons", source=oi_spec, line_width=2)

    mtf_src = ColumnDataSource(name="mtf", data={"frequency_cpmm": [], **{f"mtf_{int(k)}": [] for k in MTF_COLOURS}})
    p_mtf = figure(name="mtf_plot", width=IMAGE_PX, height=200, title="MTF", x_axis_label="cycles/mm",
                   y_axis_label="MTF", toolbar_location=None, y_range=Range1d(0, 1.02))
    for wl, colour in MTF_COLOURS.items():
        p_mtf.line("frequency_cpmm", f"mtf_{int(wl)}", source=mtf_src, color=colour, line_width=2,
                   legend_label=f"{int(wl)} nm")
    p_mtf.legend.location = "top_right"
    nyquist = Span(location=0, dimension="height", line_dash="dashed", line_color="black")
    p_mtf.add_layout(nyquist)
    psf_src = ColumnDataSource(name="psf", data={"image": [], "x": [], "y": [], "dw": [], "dh": []})
    p_psf = figure(name="psf_plot", width=IMAGE_PX, height=200, title="PSF 550 nm (µm)", toolbar_location=None,
                   match_aspect=True)
    p_psf.image(image="image", x="x", y="y", dw="dw", dh="dh", source=psf_src, palette="Viridis256")
    p_psf.grid.visible = False

    hist_src = ColumnDataSource(name="sensor_histogram",
                                data={"channel": [], "left": [], "right": [], "count": [], "colour": []})
    p_hist = figure(name="sensor_histogram_plot", width=IMAGE_PX, height=220, title="ROI pixel histogram",
                    y_axis_label="pixels", toolbar_location=None)
    p_hist.quad(left="left", right="right", bottom=0, top="count", fill_color="colour", line_color="colour",
                fill_alpha=0.4, source=hist_src)
    stats_src = ColumnDataSource(name="sensor_stats", data={"channel": [], "n": [], "mean": [], "std": [],
                                                             "snr_db": []})
    fmt = NumberFormatter(format="0.0000")
    stats_table = DataTable(source=stats_src, width=IMAGE_PX, height=130, index_position=None, columns=[
        TableColumn(field="channel", title="channel"), TableColumn(field="n", title="pixels"),
        TableColumn(field="mean", title="mean", formatter=fmt), TableColumn(field="std", title="std", formatter=fmt),
        TableColumn(field="snr_db", title="SNR (dB)", formatter=NumberFormatter(format="0.00"))])

    etendue_src = ColumnDataSource(name="etendue_map", data={"image": [], "x": [], "y": [], "dw": [], "dh": []})
    p_etendue = figure(name="etendue_plot", width=IMAGE_PX, height=200, title="Pixel optics: etendue",
                       toolbar_location=None, match_aspect=True, x_axis_location=None, y_axis_location=None)
    p_etendue.image(image="image", x="x", y="y", dw="dw", dh="dh", source=etendue_src,
                    color_mapper=LinearColorMapper(palette="Viridis256", low=0.0, high=1.0))
    p_etendue.grid.visible = False
    etendue_div = Div(name="etendue_text", width=IMAGE_PX)

    xy_src = ColumnDataSource(name="roi_xy", data={"x": [], "y": []})
    locus_src = ColumnDataSource(name="locus", data={"x": [], "y": []})
    true_src = ColumnDataSource(name="macbeth_true_xy", data={"x": [], "y": []})
    rend_src = ColumnDataSource(name="macbeth_rendered_xy", data={"x": [], "y": []})
    p_xy = figure(name="chromaticity_plot", width=IMAGE_PX, height=260, title="Chromaticity (CIE 1931 xy)",
                  x_range=Range1d(0, 0.8), y_range=Range1d(0, 0.9), toolbar_location=None, match_aspect=True)
    p_xy.line("x", "y", source=locus_src, color="black")
    p_xy.scatter("x", "y", source=true_src, size=7, fill_alpha=0, line_color="black", legend_label="true")
    p_xy.scatter("x", "y", source=rend_src, size=4, color="gray", legend_label="rendered")
    p_xy.scatter("x", "y", source=xy_src, size=10, color="red", marker="x", line_width=3, legend_label="ROI")
    p_xy.legend.location = "top_right"
    de_src = ColumnDataSource(name="delta_e", data={"patch": [], "delta_e": []})
    p_de = figure(name="delta_e_plot", width=IMAGE_PX, height=200, title="ΔE2000 per Macbeth patch",
                  x_axis_label="patch", toolbar_location=None)
    p_de.vbar(x="patch", top="delta_e", width=0.8, source=de_src)
    ip_div = Div(name="ip_text", width=IMAGE_PX)
    scene_div, oi_div, sensor_div = (Div(name=f"{w}_text", width=IMAGE_PX) for w in ("scene", "oi", "sensor"))
    mtf_div = Div(name="mtf_text", width=IMAGE_PX)

    # --- updates -----------------------------------------------------------------------
    shown: dict[str, object] = {}  # what each window / the optics plots show now: push only what changed

    def show_images() -> list[str]:
        changed = []
        for w in WINDOWS:
            img = s.image(w)
            if shown.get(w) is img:  # the session caches pictures per intermediate: same object, same picture
                continue
            shown[w] = img
            changed.append(w)
            h, wd = img.shape[:2]
            sources[w].data = {"image": [_rgba(img)], "x": [0], "y": [0], "dw": [wd], "dh": [h]}
            figs[w].x_range.update(start=0, end=wd)
            figs[w].y_range.update(start=0, end=h)
            figs[w].height = max(40, round(IMAGE_PX * h / wd))  # square pixels
            rois[w] = rois[w].fit(h, wd) if w in rois else ROI.centre(h, wd)
        return changed

    def show_roi(w: str) -> None:
        r = rois[w]
        h, _ = s.shape(w)
        boxes[w].data = {"row0": [r.row0], "row1": [r.row1], "col0": [r.col0], "col1": [r.col1],
                         "left": [r.col0], "right": [r.col1], "top": [h - r.row0], "bottom": [h - r.row1]}
        label = f"ROI rows {r.row0}:{r.row1}, columns {r.col0}:{r.col1}"
        if w in ("scene", "oi"):
            sp = s.spectrum(w, r)
            (scene_spec if w == "scene" else oi_spec).data = sp
            (scene_div if w == "scene" else oi_div).text = label
        elif w == "sensor":
            st = s.sensor_stats(r)
            edges = st["edges"]
            hist = {"channel": [], "left": [], "right": [], "count": [], "colour": []}
            for ch in st["channels"]:
                hist["channel"] += [ch["name"]] * len(ch["counts"])
                hist["left"] += list(edges[:-1])
                hist["right"] += list(edges[1:])
                hist["count"] += [int(c) for c in ch["counts"]]
                hist["colour"] += [CHANNEL_COLOURS.get(ch["name"], "#444444")] * len(ch["counts"])
            hist_src.data = hist
            stats_src.data = {k: [ch[k] if k != "channel" else ch["name"] for ch in st["channels"]]
                              for k in ("channel", "n", "mean", "std", "snr_db")}
            p_hist.xaxis.axis_label = f"raw value ({st['units']})"
            sensor_div.text = f"{label}; exposure {st['exposure_ms']:.3g} ms"
        elif w == "ip":
            cs = s.colour_stats(r)
            xy_src.data = {"x": [float(cs["roi_xy"][0])], "y": [float(cs["roi_xy"][1])]}
            locus_src.data = {"x": list(cs["locus_xy"][:, 0]), "y": list(cs["locus_xy"][:, 1])}
            if "delta_e" in cs:
                de_src.data = {"patch": list(range(1, 25)), "delta_e": [float(v) for v in cs["delta_e"]]}
                true_src.data = {"x": list(cs["true_xy"][:, 0]), "y": list(cs["true_xy"][:, 1])}
                rend_src.data = {"x": list(cs["rendered_xy"][:, 0]), "y": list(cs["rendered_xy"][:, 1])}
                p = cs["roi_patch"]
                under = "ROI outside the chart" if p is None else \
                    f"patch under ROI {p + 1} ({cs['patch_names'][p]}): {float(cs['delta_e'][p]):.2f}"
                ip_div.text = (f"{label}; xy = ({cs['roi_xy'][0]:.4f}, {cs['roi_xy'][1]:.4f})<br>ΔE2000 vs Macbeth "
                               f"(D65): mean {cs['delta_e_mean']:.2f}, max {cs['delta_e_max']:.2f}; {under}")
            else:
                for src in (de_src,):
                    src.data = {"patch": [], "delta_e": []}
                for src in (true_src, rend_src):
                    src.data = {"x": [], "y": []}
                ip_div.text = f"{label}; xy = ({cs['roi_xy'][0]:.4f}, {cs['roi_xy'][1]:.4f}) (ΔE: Macbeth scene only)"

    def show_optics() -> None:
        key = (float(s.camera.optics.f_number.reshape(-1)[0]), s.camera.sensor.pixel_size_m)
        if shown.get("optics") == key:
            return
        shown["optics"] = key
        oc = s.optics_curves()
        p_psf.visible = p_mtf.visible = oc is not None
        if oc is None:  # a ray-traced lens: its PSF varies over the field
            mtf_div.text = "PSF / MTF: a ray-traced lens varies over the field; see isettorch lens-report"
            return
        mtf_src.data = {"frequency_cpmm": list(oc["frequency_cpmm"]),
                        **{f"mtf_{int(k)}": list(v) for k, v in oc["mtf"].items()}}
        nyquist.location = oc["sensor_nyquist_cpmm"]
        n, d = oc["psf"].shape[0], oc["psf_spacing_um"]
        psf_src.data = {"image": [np.flipud(oc["psf"] / oc["psf"].max())], "x": [-n * d / 2], "y": [-n * d / 2],
                        "dw": [n * d], "dh": [n * d]}
        p_psf.title.text = f"PSF 550 nm, f/{oc['f_number']:g} (µm)"
        mtf_div.text = f"MTF: dashed line = sensor Nyquist {oc['sensor_nyquist_cpmm']:.0f} cy/mm"

    def show_etendue() -> None:
        if shown.get("etendue") is s.output.raw:
            return
        shown["etendue"] = s.output.raw
        em = s.etendue_map()
        p_etendue.visible = em is not None
        if em is None:
            etendue_src.data = {"image": [], "x": [], "y": [], "dw": [], "dh": []}
            etendue_div.text = "Pixel optics: none (the sensor's pixel_optics is not set)"
            return
        h, wd = em["map"].shape
        etendue_src.data = {"image": [np.flipud(em["map"])], "x": [0], "y": [0], "dw": [wd], "dh": [h]}
        etendue_div.text = (f"Pixel optics ({em['method']}): etendue {em['centre']:.3f} at the centre, "
                            f"{em['corner']:.3f} at the corner (CRA {em['corner_cra_deg']:.1f} deg)")

    def refresh(timings=None) -> None:
        t0 = time.perf_counter()
        for w in show_images():
            show_roi(w)
        show_optics()
        show_etendue()
        t = timings or s.timings
        upd = time.perf_counter() - t0 + t["camera_s"]
        renders = status.data["renders"][0] + 1
        status.data = {"renders": [renders], "camera_s": [t["camera_s"]], "update_s": [upd]}
        status_div.text = (f"camera <b>{s.config_name}</b>, scene <b>{s.settings.scene}</b>: "
                           f"render {t['camera_s']:.3f} s, render + analyses {upd:.3f} s (#{renders})")

    def on_select(w):
        def cb(event):
            if not event.final or event.geometry.get("type") != "rect":
                return
            g = event.geometry
            h, wd = s.shape(w)
            rois[w] = ROI.from_box(g["x0"], g["x1"], g["y0"], g["y1"], h, wd)
            show_roi(w)
        return cb

    for w in WINDOWS:
        figs[w].on_event(SelectionGeometry, on_select(w))

    # --- controls ------------------------------------------------------------------------
    d = s.defaults
    scene_names = list(SCENES) if s.settings.scene in SCENES else [s.settings.scene, *SCENES]
    w_scene = Select(name="scene_select", title="Scene", value=s.settings.scene, options=scene_names, width=150)
    w_f = Select(name="f_number_select", title="f-number", value=f"{d['f_number']:g}", width=90,
                 options=sorted({f"{v:g}" for v in (*F_NUMBERS, d["f_number"])}, key=float),
                 disabled=not s.f_number_settable)
    w_exp = Select(name="exposure_select", title="Exposure (ms)", value="config", width=110,
                   options=["config"] + [f"{v:g}" for v in EXPOSURES_MS if v is not None])
    w_px = Select(name="pixel_size_select", title="Pixel size (µm)", value=f"{d['pixel_size_um']:g}", width=110,
                  options=sorted({f"{v:g}" for v in (*PIXEL_SIZES_UM, d["pixel_size_um"])}, key=float))
    cfas = list(CFAS) if d["cfa"] in CFAS else [d["cfa"], *CFAS]
    w_cfa = RadioButtonGroup(name="cfa_buttons", labels=cfas, active=cfas.index(d["cfa"]))
    w_noise = Toggle(name="noise_toggle", label="noise", active=bool(d["noise"]), width=80)
    from ..isp.demosaicing import METHODS

    methods = [m for m in ("nearest", "bilinear", "malvar2004", "menon2007") if m in METHODS]
    if d["demosaic"] not in methods:
        methods.insert(0, d["demosaic"])
    w_dm = RadioButtonGroup(name="demosaic_buttons", labels=methods, active=methods.index(d["demosaic"]))

    reverting = []

    def rerender(widget, attr, old, **changes) -> None:
        if reverting:  # the widget being put back after a rejected change: the session never left ``old``
            return
        try:
            timings = s.update(**changes)
        except (ValueError, TypeError, RuntimeError) as err:  # show the library's message, keep the last render
            status_div.text = f"<span style='color:#b00'>error: {err}</span>"
            reverting.append(True)  # the widget shows the settings the images were made with
            try:
                setattr(widget, attr, old)
            finally:
                reverting.clear()
            return
        refresh(timings)

    w_scene.on_change("value", lambda a, o, v: rerender(w_scene, a, o, scene=v))
    w_f.on_change("value", lambda a, o, v: rerender(w_f, a, o, f_number=float(v)))
    w_exp.on_change("value", lambda a, o, v: rerender(w_exp, a, o, exposure_ms=None if v == "config" else float(v)))
    w_px.on_change("value", lambda a, o, v: rerender(w_px, a, o, pixel_size_um=float(v)))
    w_cfa.on_change("active", lambda a, o, v: rerender(w_cfa, a, o, cfa=cfas[v]))
    w_noise.on_change("active", lambda a, o, v: rerender(w_noise, a, o, noise=bool(v)))
    w_dm.on_change("active", lambda a, o, v: rerender(w_dm, a, o, demosaic=methods[v]))

    refresh()
    header = Div(text="<b>isettorch view</b>: drag a box on any image to choose its region of interest")
    controls = row(w_scene, w_f, w_exp, w_px, column(Div(text="CFA"), w_cfa), column(Div(text="Noise"), w_noise),
                   column(Div(text="Demosaic"), w_dm))
    # Images in their own row: a column would align their frames with the axes of the plots below.
    images = row(*[column(Div(text=f"<h3>{TITLES[w]}</h3>"), figs[w], width=IMAGE_PX + 10) for w in WINDOWS])
    cols = [
        column(scene_div, p_scene),
        column(oi_div, p_oi, p_psf, p_mtf, mtf_div),
        column(sensor_div, p_hist, stats_table, etendue_div, p_etendue),
        column(ip_div, p_xy, p_de),
    ]
    doc.add_root(column(header, controls, status_div, images, row(*cols), _status_holder(status)))
    doc.title = "isettorch view"


def _status_holder(status):
    """An invisible plot that holds the ``status`` source so it is part of the document (read by tests)."""
    from bokeh.plotting import figure

    f = figure(width=1, height=1, toolbar_location=None, visible=False)
    f.scatter("renders", "camera_s", source=status)
    return f


def make_server(session_factory, port: int = 5006, address: str = "127.0.0.1"):
    """A Bokeh ``Server`` serving the viewer at ``http://address:port/`` (not started)."""
    from bokeh.application import Application
    from bokeh.application.handlers.function import FunctionHandler
    from bokeh.server.server import Server

    app = Application(FunctionHandler(lambda doc: make_document(doc, session_factory)))
    origins = [f"{address}:{port}", f"localhost:{port}", f"127.0.0.1:{port}"]
    return Server({"/": app}, port=port, address=address, allow_websocket_origin=origins, num_procs=1)


def serve(config="default", scene: str = "macbeth", size: int = 256, seed: int = 0, port: int = 5006,
          address: str = "127.0.0.1", open_browser: bool = True) -> None:
    """Serve the viewer until interrupted. A session (camera, scene, render) is created for each browser tab."""
    ViewerSession(config, scene, size, seed)  # fail here, with the library's message, on a bad config or scene
    server = make_server(lambda: ViewerSession(config, scene, size, seed), port, address)
    server.start()
    print(f"isettorch view: serving http://{address}:{port}/ (Ctrl+C stops)", flush=True)
    if open_browser:
        server.io_loop.add_callback(server.show, "/")
    try:
        server.io_loop.start()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
