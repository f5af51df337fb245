"""An independent NumPy port of ISETCam's mlRadiance (with mlCoordinates, mlSource, mlLens, mlDisplacement,
mlPropagate, ffndgrid, mlensGet('optimal offset') and mlAnalyzeArrayEtendue), written for this project's microlens
audit from the MATLAB source at ISET/isetcam commit 3aaefc8: the reference of tests/sensor/test_microlens.py's ISETCam
tables (imported as ``isetcam_mlradiance``; pytest puts ``tests/`` on the path). All lengths in microns, as
ISETCam's internals."""
import numpy as np

N = 255


def mround(v):  # MATLAB round: half away from zero
    return np.sign(v) * np.floor(np.abs(v) + 0.5)


def ffndgrid(xcol, ucol, f, xl, xu, ul, uu, n=N):
    """ffndgrid([x u], f, -n, [xl xu ul uu], 1): mean per cell, out-of-range dropped, empty -> 0.
    Returns grid [u_index, x_index] (meshgrid layout)."""
    dx = (xu - xl) / (n - 1)
    du = (uu - ul) / (n - 1)
    bx = mround((xcol - xl) / dx)  # 0-based
    bu = mround((ucol - ul) / du)
    fL, fU = f.min(), f.max()
    ok = (bx >= 0) & (bx <= n - 1) & (bu >= 0) & (bu <= n - 1) & (f >= fL) & (f <= fU)
    bx, bu, fv = bx[ok].astype(int), bu[ok].astype(int), f[ok]
    lin = bu * n + bx
    s = np.bincount(lin, weights=fv, minlength=n * n)
    c = np.bincount(lin, minlength=n * n)
    out = np.zeros(n * n)
    nz = s != 0
    out[nz] = s[nz] / c[nz]
    return out.reshape(n, n)


def ml_radiance(cra_deg=0.0, ml_flag=1, offset_um=0.0, source_fnumber=4.0, ml_focal_um=7.0, ml_fnumber=2.5,
                pixel_um=2.8, pd_um=2.8 * 0.75**0.5, d_stack=(2.0, 5.0), n_stack=(1, 2.0, 1.46, 3.5),
                lambda_um=0.5, return_all=False):
    mlAperture = ml_focal_um / ml_fnumber
    widthPS = 2 * mlAperture
    rStack = 1.52
    f = ml_focal_um / rStack
    x = np.linspace(-widthPS, widthPS, N)
    p = np.linspace(-0.99, 0.99, N)
    X, P = np.meshgrid(x, p)
    sourceNA = 1.0 * np.sin(np.arctan(1 / (2 * source_fnumber)))
    s = np.sin(cra_deg / 180 * np.pi)
    u1, u2 = s - sourceNA, s + sourceNA
    x1, x2 = -mlAperture / 2, mlAperture / 2
    W = np.zeros((N, N))
    W[np.ix_((p > u1) & (p < u2), (x > x1) & (x < x2))] = 1
    W_source = W.copy()
    lim = (x.min(), x.max(), p.min(), p.max())
    Xf, Pf = X.ravel(order="F"), P.ravel(order="F")  # MATLAB X(:) column-major
    def flat(Wm):
        return Wm.ravel(order="F")
    if ml_flag:
        W = ffndgrid(Xf, Pf + np.sin(np.arctan(Xf / f)), flat(W), *lim)
        W = ffndgrid(Xf + offset_um, Pf, flat(W), *lim)
    for ii in range(len(d_stack)):
        d, n = d_stack[ii], n_stack[ii + 1]
        W = ffndgrid(Xf - d * np.tan(np.arcsin(Pf / n)), Pf, flat(W), *lim)
    W_det = W
    proj = W_det.sum(0)
    psProjected = proj / proj.max() if proj.max() > 0 else proj * np.nan
    pixIrr = np.outer(psProjected, psProjected)
    IrrIn = W_source.sum(0)
    eIn = IrrIn[np.abs(x) < pixel_um / 2].sum()
    IrrOut = W_det.sum(0)
    eOut = IrrOut[np.abs(x) < pd_um / 2].sum()
    E = eOut / eIn
    if return_all:
        return dict(E=E, x=x, p=p, irr=pixIrr, W_source=W_source, W_det=W_det)
    return E


def optimal_offset_um(cra_deg, d_stack=(2.0, 5.0), n_stack=(1, 2.0, 1.46, 3.5)):
    cra = np.deg2rad(cra_deg)
    nS = n_stack[1:-1]
    val = 0.0
    for z, n in zip(d_stack, nS):
        val = z * np.tan(np.arcsin(np.sin(cra) / n)) + val
    return val


def ml_etendue(cra_deg, method, offset_um=None, **kw):
    """mlAnalyzeArrayEtendue per angle."""
    d_stack, n_stack = kw.get("d_stack", (2.0, 5.0)), kw.get("n_stack", (1, 2.0, 1.46, 3.5))
    if method == "centered":
        return ml_radiance(cra_deg, 1, 0.0 if offset_um is None else offset_um, **kw)
    if method == "optimal":
        o = optimal_offset_um(cra_deg, d_stack, n_stack)
        return ml_radiance(cra_deg, 1, o + (0 if offset_um is None else offset_um), **kw)
    if method == "none":
        return ml_radiance(cra_deg, 0, 0.0, **kw)
    raise ValueError(method)


def analyze_array_etendue(rows, cols, pixel_um, source_fl_um, method, n_angles=5, **kw):
    """mlAnalyzeArrayEtendue: absolute etendue map interpolated in CRA (deg) from nAngles+1 samples."""
    ys = np.linspace(-rows * pixel_um / 2 + pixel_um / 2, rows * pixel_um / 2 - pixel_um / 2, rows)
    xs = np.linspace(-cols * pixel_um / 2 + pixel_um / 2, cols * pixel_um / 2 - pixel_um / 2, cols)
    X, Y = np.meshgrid(xs, ys)
    sensorCRA = np.rad2deg(np.arctan(np.sqrt(X ** 2 + Y ** 2) / source_fl_um))
    cra = np.arange(n_angles + 1) / n_angles * sensorCRA.max()
    et = np.array([ml_etendue(c, method, pixel_um=pixel_um, **kw) for c in cra])
    return np.interp(sensorCRA.ravel(), cra, et).reshape(sensorCRA.shape), cra, et, sensorCRA
