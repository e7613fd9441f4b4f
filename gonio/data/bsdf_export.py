"""Export a BRDF as an RGL ``.bsdf`` file (Dupuy & Jakob 2018): isotropic or anisotropic, RGB or spectral.

What renderers read: Mitsuba 3's ``measured`` plugin and pbrt-v4's ``measured`` material; the
project's own reader is :mod:`gonio.data.formats.rgl_bsdf` (``gonio import rgl-bsdf``). The
source is any *BRDF callable* ``beta(w_i, w_o) -> (N, bands)`` (the radiance coefficient
``beta = pi f_r`` at unit fabric-frame directions ``(N, 3)``): a fabric model evaluated on demand
(:mod:`simulate.export`) or a measured dataset (:mod:`gonio.data.bsdf_dataset`). Only the
direction pairs the tensor needs are asked for, in two batches:

1. **NDF** ``D`` (128 nodes over ``u = sqrt(2 theta / pi)``; the retro-reflection asked at 32
   directions, 8 for Monte Carlo sources, interpolated in ``u``). Dupuy & Jakob's power iteration on
   the retro-reflection: a microfacet BRDF has ``f(w, w) = F D(w) / (4 cos(theta) sigma(w))`` with
   Smith's ``G1 = cos / sigma``, hence ``D(w) ~ f_Y(w, w) cos(theta) sigma(w)``, iterated with
   ``sigma(w) = int D(m) <w, m>+ dm`` and ``int D cos = 1`` (``f_Y``: the luminance of ``f``). A
   floor of 1e-3 of the peak keeps every half vector reachable. ``sigma`` is tabulated (128
   nodes) by quadrature of the tabulated ``D``.
2. **VNDF warps** per incidence node: ``vndf[u] ~ D(m) <w_i, m>+ u_theta sin(theta_m)`` (the
   visible normals times the Jacobian of the ``u -> m`` map, as in the RGL files), 128 x 128.
3. **Values** on the *warped* grid (``res x res``, default 32): for each grid point ``s`` the half
   vector ``m = VNDF(s)`` (the exact inverse of the reader's, i.e. Mitsuba's, continuous
   ``Marginal2D`` inversion), ``w_o = 2 (m . w_i) m - w_i`` and the stored value
   ``S = f_r cos(theta_o) 4 sigma(w_i) / D(m)`` with ``D`` and ``sigma`` interpolated exactly as
   the renderer will (``jacobian = 1``). Grid points whose ``w_o`` is below the horizon are
   stored as 0 and flagged in ``valid`` (as the RGL files do). ``luminance`` = ``Y`` of ``S``
   (Rec. 709 weights for RGB; the CIE ``y`` bar weighting of the file's wavelengths for spectra):
   the renderer samples it before the VNDF warp, so its sampling density is ``~ Y(f_r cos)``.

Anisotropic export (``reduction`` 1, 2 or 4, :func:`fit_ndf_2d`): the NDF and ``sigma`` become
tables over the half vector's / incidence's azimuth too (33 x 128), the retro-reflection is asked
on 16 zenith x 5 azimuth directions inside the stored azimuth range, and there are ``n_phi_i``
incidence azimuths over ``[-pi, -pi + 2 pi / reduction]`` (Mitsuba mirrors every incidence into
that range by ``x -> -x`` and/or ``y -> -y``: the source must have those mirror symmetries, as
a plain weave's warp/weft summation has).

Renderers. Mitsuba 3 reads RGB files (``rgb``) in its RGB variants and spectral files
(``spectra`` + ``wavelengths``) in its spectral variants, isotropic and any ``reduction``.
pbrt-v4 (``MeasuredBRDF::Create``, ``src/pbrt/bxdfs.cpp``) reads spectral files only and, when
anisotropic, only ``reduction = 1`` (incidence azimuths over the full circle).

Incidence nodes: ``theta_i`` in 0..90 deg (default 16, uniform in ``cos(theta_i)``: dense towards
grazing, where the specular lobe and Fresnel change fastest); the 90 deg node holds the
model's values at :data:`GRAZING_EVAL_DEG` (models refuse ``cos(theta_i) = 0``). Anisotropic
sources are exported isotropically: the values are averaged over the azimuths ``azimuths_deg``
of the incidence (stated in the description and provenance).

Tabulation error: the largest errors sit near the mirror direction at large incidence (half
vectors near the normal, which the ``u = sqrt(2 theta / pi)`` warp resolves coarsely for a broad
NDF) and in a model's grazing forward Fresnel peak; :data:`STATED_TABULATION_ERROR` is the bound
the tests hold exports to (the measured errors: docs/notes/implementation.md, "RGL .bsdf export").

References
----------
J. Dupuy, W. Jakob, "An Adaptive Parameterization for Efficient Material Acquisition and
Rendering", ACM TOG 37(6), 2018 (sections 4-5: NDF by power iteration, VNDF warp). Mitsuba 3
``src/bsdfs/measured.cpp`` and ``include/mitsuba/core/distr_2d.h`` (``Marginal2D``, continuous),
``src/core/tensor.cpp`` (the tensor file); rgl-epfl/brdf-loader; pbrt-v4 ``MeasuredBxDF``.
Learned from, not copied.
"""

from __future__ import annotations

import json
import logging
import os
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from gonio.data.dataset import DatasetError, atomic_write

__all__ = ["BRDF", "ExportError", "ExportResult", "STATED_TABULATION_ERROR", "build_fields",
           "export_bsdf", "incidence_nodes", "tabulation_error", "write_tensor_file"]

#: ``beta(w_i, w_o) -> (N, bands)`` at unit fabric-frame direction arrays ``(N, 3)``.
BRDF = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: The incidence of the 90 deg node at which a source is evaluated.
GRAZING_EVAL_DEG = 89.5
#: What an export with the defaults achieves against a smooth source (relative error of beta over
#: random pairs with both zenith angles <= theta_max, by theta_max in degrees); the measured
#: figures are in the module docstring.
STATED_TABULATION_ERROR = {60.0: {"rms": 0.01, "p95": 0.02, "max": 0.10},
                           80.0: {"rms": 0.02, "p95": 0.03, "max": 0.40}}
REC709_Y = np.array([0.212671, 0.715160, 0.072169])
log = logging.getLogger(__name__)
_DTYPE_CODES = {np.dtype(np.uint8): 1, np.dtype(np.uint32): 5, np.dtype(np.float32): 10}


class ExportError(DatasetError):
    """A source that cannot be exported (one line: what and what to do)."""


@dataclass
class ExportResult:
    """What an export to an RGL `.bsdf` file wrote (`fabric_optics.export_bsdf`, `gonio export`, `simulate export`).

    Attributes
    ----------
    path : str
        The file written.
    fields : dict of str to numpy.ndarray
        The tensor fields as written (`theta_i`, `phi_i`, `spectra` or `rgb`, `ndf`, `vndf`, `luminance`, ...).
    evaluations : int
        Model (or interpolation) evaluations the tabulation took.
    valid_fraction : float
        Share of the tabulated direction pairs with a value (the rest lie below the horizon).
    error : dict, optional
        With `check_pairs`: the tabulation error measured at random direction pairs; None otherwise.
    provenance : dict
        What the file records of its source; for a dataset, `"coverage"` says which directions it
        covers and how the others are filled.
    """

    path: str
    fields: dict[str, np.ndarray]
    evaluations: int
    valid_fraction: float
    error: dict[str, Any] | None = None
    provenance: dict[str, Any] = field(default_factory=dict)


def write_tensor_file(path: str | os.PathLike, fields: dict[str, np.ndarray]) -> None:
    r"""Write Mitsuba's ``tensor_file`` (little-endian, version 1.0), atomically.

    Header: ``tensor_file\0``, version bytes ``1, 0``, field count (uint32); per field the name
    (uint16 length + UTF-8), ndim (uint16), dtype code (uint8), data offset (uint64), shape
    (ndim x uint64); the data follow, each field 8-byte aligned.
    """
    items = [(name, np.ascontiguousarray(a)) for name, a in fields.items()]
    header = bytearray(b"tensor_file\0" + struct.pack("<BBI", 1, 0, len(items)))
    header_size = len(header) + sum(2 + len(n.encode()) + 2 + 1 + 8 + 8 * a.ndim for n, a in items)
    offset = (header_size + 7) // 8 * 8
    blobs, offsets = [], []
    for _name, a in items:
        if a.dtype not in _DTYPE_CODES:
            raise TypeError(f"tensor field dtype {a.dtype} not supported")
        offsets.append(offset)
        data = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
        pad = (-len(data)) % 8
        blobs.append(data + b"\0" * pad)
        offset += len(data) + pad
    for (name, a), off in zip(items, offsets, strict=True):
        raw = name.encode()
        header += struct.pack("<H", len(raw)) + raw
        header += struct.pack("<HBQ", a.ndim, _DTYPE_CODES[a.dtype], off)
        header += struct.pack("<" + "Q" * a.ndim, *a.shape)
    header += b"\0" * (offsets[0] - len(header) if offsets else 0)
    atomic_write(path, bytes(header) + b"".join(blobs))


def _theta2u(theta):
    return np.sqrt(np.asarray(theta) * (2.0 / np.pi))


def _u2theta(u):
    return np.asarray(u) ** 2 * (np.pi / 2.0)


def _hemisphere_dirs(theta, phi):
    t, p = np.broadcast_arrays(np.asarray(theta, float), np.asarray(phi, float))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def _projected_area(d_nodes: np.ndarray, theta: np.ndarray, n_t: int = 256, n_p: int = 128) -> np.ndarray:
    """``sigma(theta) = int D(m) <w(theta), m>+ dm`` (midpoint rule in ``u`` and ``phi``)."""
    u = (np.arange(n_t) + 0.5) / n_t
    tm = _u2theta(u)
    pm = (np.arange(n_p) + 0.5) / n_p * 2 * np.pi - np.pi
    d = np.interp(u, np.linspace(0, 1, d_nodes.size), d_nodes)
    # d omega = sin(theta_m) pi u du dphi  (theta = u^2 pi / 2)
    weight = d * np.sin(tm) * np.pi * u / n_t * (2 * np.pi / n_p)
    st, ct = np.sin(tm)[:, None], np.cos(tm)[:, None]
    out = np.empty(theta.size)
    for k, th in enumerate(np.ravel(theta)):
        dot = np.sin(th) * st * np.cos(pm)[None, :] + np.cos(th) * ct
        out[k] = float(np.sum(weight[:, None] * np.clip(dot, 0, None)))
    return out


def fit_ndf(retro_y: Callable[[np.ndarray], np.ndarray], n: int = 128, iterations: int = 8,
            n_retro: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """NDF and projected-area tables (``n`` nodes over ``u``) by Dupuy & Jakob's power iteration.

    ``retro_y(theta)``: the luminance of ``f_r(w, w)`` at zenith angles ``theta`` (radians),
    asked at ``n_retro`` angles uniform in ``u`` and interpolated linearly in ``u`` to the ``n``
    nodes (each retro direction is a distinct incidence: for a Monte Carlo source, a run).
    """
    u = np.linspace(0, 1, n)
    theta = _u2theta(u)
    u_r = np.linspace(0, 1, max(2, min(n_retro, n)))
    f_r = np.asarray(retro_y(np.minimum(_u2theta(u_r), np.radians(GRAZING_EVAL_DEG))), float)
    f = np.clip(np.interp(u, u_r, f_r), 0, None)
    if not np.any(f > 0):
        raise ExportError("the source reflects nothing back towards the source (retro-reflection "
                          "is zero everywhere): no NDF can be derived")
    d = np.full(n, 1.0 / np.pi)
    for _ in range(iterations):
        sigma = _projected_area(d, theta)
        d = f * np.cos(theta) * sigma
        d = np.maximum(d, 1e-3 * d.max())
        d = d / _projected_area(d, np.zeros(1))[0]      # int D cos = sigma(normal) = 1
    return d, _projected_area(d, theta)


def _segment(r0, r1, target):
    """``t`` in [0, 1] with ``r0 t + (r1 - r0) t^2 / 2 = target`` (stable quadratic root)."""
    disc = np.maximum(r0 * r0 + 2 * (r1 - r0) * target, 0.0)
    denom = r0 + np.sqrt(disc)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(denom > 0, 2 * target / denom, 0.0)
    return np.clip(t, 0.0, 1.0)


def warp_forward(table: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Continuous ``Marginal2D`` sample warp of a bilinear ``(H, W)`` table: ``s -> u``.

    The exact inverse of :meth:`gonio.data.formats.rgl_bsdf._Marginal2D.invert` (Mitsuba's
    ``invert``): marginal in ``y`` (rows) first, then ``x`` conditional on the interpolated row.
    """
    d = np.asarray(table, float)
    h, w = d.shape
    px, py = 1.0 / (w - 1), 1.0 / (h - 1)
    cond = np.cumsum(0.5 * px * (d[:, :-1] + d[:, 1:]), axis=-1)
    rows = cond[:, -1]
    marg = np.cumsum(0.5 * py * (rows[:-1] + rows[1:]))
    norm = 1.0 / marg[-1]
    d, cond, rows, marg = d * norm, cond * norm, rows * norm, marg * norm
    sx, sy = np.clip(s[..., 0], 0, 1), np.clip(s[..., 1], 0, 1)
    k = np.clip(np.searchsorted(marg, sy, side="right"), 0, h - 2)
    prev = np.where(k > 0, marg[np.maximum(k - 1, 0)], 0.0)
    ty = _segment(rows[k], rows[k + 1], (sy - prev) / py)
    y = (k + ty) * py
    c_rows = cond[k] * (1 - ty)[:, None] + cond[k + 1] * ty[:, None]        # (N, W-1)
    target = sx * c_rows[:, -1]
    i = np.clip(np.sum(c_rows <= target[:, None], axis=1), 0, w - 2)
    n = np.arange(sx.size)
    prev_x = np.where(i > 0, c_rows[n, np.maximum(i - 1, 0)], 0.0)
    v = d[k] * (1 - ty)[:, None] + d[k + 1] * ty[:, None]
    tx = _segment(v[n, i], v[n, i + 1], (target - prev_x) / px)
    return np.stack([(i + tx) * px, y], axis=-1)


def _luminance_weights(wavelengths_nm: np.ndarray | None) -> np.ndarray:
    if wavelengths_nm is None:
        return REC709_Y
    import colour

    cmf = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    ybar = np.interp(wavelengths_nm, cmf.wavelengths, cmf.values[:, 1], left=0.0, right=0.0)
    if ybar.sum() <= 0:
        return np.full(wavelengths_nm.size, 1.0 / wavelengths_nm.size)
    return ybar / ybar.sum()


def incidence_nodes(n: int) -> np.ndarray:
    """``n`` incidence angles (degrees) from 0 to 90, uniform in ``cos(theta_i)``."""
    if n < 2:
        raise ExportError(f"{n} incidence node(s): at least 2 are needed (0 and 90 deg)")
    return np.degrees(np.arccos(np.linspace(1.0, 0.0, n)))


def _bilinear(table: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Mitsuba's ``Marginal2D.eval`` without parameters: ``table`` (H, W) at ``u`` = (x, y)."""
    h, w = table.shape
    pos = np.clip(u, 0.0, 1.0) * np.array([w - 1, h - 1])
    off = np.minimum(pos.astype(np.intp), np.array([w - 2, h - 2]))
    fx, fy = (pos - off)[..., 0], (pos - off)[..., 1]
    ox, oy = off[..., 0], off[..., 1]
    return ((1 - fy) * ((1 - fx) * table[oy, ox] + fx * table[oy, ox + 1])
            + fy * ((1 - fx) * table[oy + 1, ox] + fx * table[oy + 1, ox + 1]))


def fold(w: np.ndarray, reduction: int) -> np.ndarray:
    """Mitsuba's mirroring of directions into the stored azimuth range (``reduction`` 2 or 4)."""
    w = np.array(w, float, copy=True)
    if reduction >= 2:
        sy = w[..., 1].copy()
        sx = w[..., 0].copy() if reduction == 4 else sy
        w[..., 0] = np.where(sx >= 0, -w[..., 0], w[..., 0])
        w[..., 1] = np.where(sy >= 0, -w[..., 1], w[..., 1])
    return w


class _Sigma2D:
    """``sigma(w) = int D(m) <w, m>+ dm`` at fixed directions ``dirs`` (K, 3) for any NDF table.

    The clipped cosines ``<w, m>+`` on the quadrature grid of ``m`` (midpoints in ``u_theta`` and
    ``phi``) are computed once; each NDF is then one matrix-vector product.
    """

    def __init__(self, dirs: np.ndarray, n_t: int = 128, n_p: int = 64):
        u = (np.arange(n_t) + 0.5) / n_t
        up = (np.arange(n_p) + 0.5) / n_p
        uu, pp = np.meshgrid(u, up, indexing="ij")
        m = _hemisphere_dirs(_u2theta(uu), (2 * pp - 1) * np.pi).reshape(-1, 3)
        self.u_m = np.stack([uu.ravel(), pp.ravel()], -1)
        self.measure = np.sin(_u2theta(uu.ravel())) * np.pi * uu.ravel() / n_t * (2 * np.pi / n_p)
        self.kernel = np.clip(np.asarray(dirs, float) @ m.T, 0, None).astype(np.float32)

    def __call__(self, ndf: np.ndarray) -> np.ndarray:
        weight = (_bilinear(ndf, self.u_m) * self.measure).astype(np.float32)
        return (self.kernel @ weight).astype(float)


def _grid_dirs(h: int, w: int) -> np.ndarray:
    """Directions at the nodes of an ``(h u_phi rows, w u_theta columns)`` table, row-major."""
    uu = np.stack(np.meshgrid(np.linspace(0, 1, w), np.linspace(0, 1, h)), -1)
    return _hemisphere_dirs(_u2theta(uu[..., 0]), (2 * uu[..., 1] - 1) * np.pi).reshape(-1, 3)


def fit_ndf_2d(retro_y: Callable[[np.ndarray], np.ndarray], reduction: int, shape: tuple[int, int] = (33, 128),
               n_retro: tuple[int, int] = (16, 5), iterations: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Anisotropic NDF and sigma tables ``(u_phi rows, u_theta columns)`` by the power iteration.

    ``retro_y(w)`` (unit directions ``(K, 3)``) is asked only inside the stored azimuth range
    (``n_retro`` = zenith x azimuth samples there); other azimuths are mirrored into it. The
    ``sigma`` table is 17 x 32 (smooth; computed once per iteration there and interpolated).
    """
    from scipy.interpolate import RegularGridInterpolator

    h, w = shape
    nodes = _grid_dirs(h, w)                                        # (h * w, 3), row-major
    u_nodes = np.stack(np.meshgrid(np.linspace(0, 1, w), np.linspace(0, 1, h)), -1).reshape(-1, 2)
    theta_n = _u2theta(u_nodes[:, 0])
    ur = np.linspace(0, 1, n_retro[0])
    span = 2 * np.pi / max(reduction, 1)
    pr = np.linspace(-np.pi, -np.pi + span, n_retro[1])
    gt, gp = np.meshgrid(_u2theta(ur), pr, indexing="ij")
    grid_dirs = _hemisphere_dirs(np.minimum(gt, np.radians(GRAZING_EVAL_DEG)), gp).reshape(-1, 3)
    f_grid = np.clip(np.asarray(retro_y(grid_dirs), float).reshape(gt.shape), 0, None)
    if not np.any(f_grid > 0):
        raise ExportError("the source reflects nothing back towards the source: no NDF can be derived")
    interp = RegularGridInterpolator((ur, pr), f_grid, bounds_error=False, fill_value=None)
    fn = fold(nodes, reduction)
    phi_f = np.clip(np.arctan2(fn[:, 1], fn[:, 0]), pr[0], pr[-1])
    f = np.clip(interp(np.stack([u_nodes[:, 0], phi_f], -1)), 0, None)
    # sigma is smooth: computed on a coarser table and interpolated to the NDF's nodes
    hc, wc = 17, 32
    sigma_of = _Sigma2D(_grid_dirs(hc, wc))
    normal = _Sigma2D(np.array([[0.0, 0.0, 1.0]]))
    d = np.full(h * w, 1.0 / np.pi)
    for _ in range(iterations):
        sig = _bilinear(sigma_of(d.reshape(h, w)).reshape(hc, wc), u_nodes)
        d = f * np.cos(theta_n) * sig
        d = np.maximum(d, 1e-3 * d.max())
        d = d / normal(d.reshape(h, w))[0]
    ndf = d.reshape(h, w)
    return ndf, sigma_of(ndf).reshape(hc, wc)


def build_fields(brdf: BRDF, *, wavelengths_nm: npt.ArrayLike | None = None,
                 theta_i_deg: npt.ArrayLike | None = None, res: int = 64,
                 azimuths_deg: Sequence[float] = (0.0,), description: str = "",
                 provenance: dict | None = None, n_retro: int = 32, reduction: int = 0,
                 n_phi_i: int = 5) -> tuple[dict[str, np.ndarray], int]:
    """The tensor fields of ``brdf`` (spectral when ``wavelengths_nm`` is given, else RGB).

    ``reduction`` 0: isotropic (``phi_i = 0``, half-vector azimuth relative to the incidence,
    values averaged over ``azimuths_deg``). 1, 2 or 4: anisotropic, ``n_phi_i`` incidence
    azimuths over ``[-pi, -pi + 2 pi / reduction]`` (Mitsuba mirrors the rest into that range:
    the source must have those mirror symmetries), absolute half-vector azimuths.
    Returns the fields and the number of direction pairs the source was evaluated at.
    """
    wl = None if wavelengths_nm is None else np.asarray(wavelengths_nm, float)
    ylum = _luminance_weights(wl)
    nodes = np.radians(np.asarray(theta_i_deg if theta_i_deg is not None else incidence_nodes(16), float))
    if nodes.size < 2 or nodes[0] != 0 or abs(nodes[-1] - np.pi / 2) > 1e-9 or np.any(np.diff(nodes) <= 0):
        raise ExportError("incidence nodes must increase from 0 to 90 deg (at least 2)")
    if res < 4:
        raise ExportError(f"value resolution {res} is too small (at least 4)")
    if reduction not in (0, 1, 2, 4) or (reduction and n_phi_i < 3):
        raise ExportError("reduction must be 0 (isotropic), 1, 2 or 4, with at least 3 incidence azimuths")
    rot = np.radians(np.asarray(azimuths_deg if not reduction else (0.0,), float))
    evaluations = 0

    def f_r(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``f_r`` averaged over the rotations of the pair about the normal: ``(N, bands)``."""
        nonlocal evaluations
        log.info("bsdf export: asking the source for %d direction pairs x %d azimuth(s)", wi.shape[0], rot.size)
        total = None
        for a in rot:
            c, s = np.cos(a), np.sin(a)
            rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
            b = np.asarray(brdf(wi @ rz.T, wo @ rz.T), float).reshape(wi.shape[0], -1)
            evaluations += wi.shape[0]
            total = b if total is None else total + b
        assert total is not None
        return np.nan_to_num(total / rot.size / np.pi, nan=0.0)

    if reduction:
        phis = np.linspace(-np.pi, -np.pi + 2 * np.pi / reduction, n_phi_i)
        n_r = (16, 5) if n_retro >= 32 else (max(4, n_retro // 2), 3)     # each one a run for Monte Carlo
        ndf, sigma = fit_ndf_2d(lambda w: f_r(w, w) @ ylum, reduction, n_retro=n_r)
    else:
        phis = np.zeros(1)
        d1, s1 = fit_ndf(lambda t: f_r(_hemisphere_dirs(t, 0.0), _hemisphere_dirs(t, 0.0)) @ ylum,
                         n_retro=n_retro)
        ndf, sigma = np.stack([d1, d1]), np.stack([s1, s1])
    ndf32, sigma32 = ndf.astype(np.float32), sigma.astype(np.float32)
    ug = np.linspace(0, 1, 128)
    uu = np.stack(np.meshgrid(ug, ug), -1)                          # (rows u_phi, cols u_theta, 2)
    m_grid = _hemisphere_dirs(_u2theta(uu[..., 0]), (2 * uu[..., 1] - 1) * np.pi)
    d_grid = _bilinear(ndf, uu) * ug[None, :] * np.sin(_u2theta(ug))[None, :]
    vndf = np.empty((phis.size, nodes.size, 128, 128), np.float32)
    g = (np.arange(res) + 0.0) / (res - 1)
    sx, sy = np.meshgrid(g, g)                       # rows: s_y, columns: s_x
    s = np.stack([sx.ravel(), sy.ravel()], axis=-1)
    pairs_i, pairs_o, where, factor = [], [], [], []
    valid = np.zeros((phis.size, nodes.size, res, res), bool)
    for p, phi in enumerate(phis):
        for j, t in enumerate(nodes):
            wi = _hemisphere_dirs(t, phi)
            vndf[p, j] = d_grid * np.clip(m_grid @ wi, 0, None)
            um = warp_forward(vndf[p, j].astype(float), s)
            m = _hemisphere_dirs(_u2theta(um[:, 0]), (2 * um[:, 1] - 1) * np.pi + (0.0 if reduction else phi))
            wo = 2 * (m @ wi)[:, None] * m - wi
            ok = wo[:, 2] > 1e-6
            valid[p, j] = ok.reshape(res, res)
            wi_eval = _hemisphere_dirs(min(t, np.radians(GRAZING_EVAL_DEG)), phi)
            pairs_i.append(np.broadcast_to(wi_eval, (int(ok.sum()), 3)))
            pairs_o.append(wo[ok] / np.linalg.norm(wo[ok], axis=-1, keepdims=True))
            where.append((p, j, np.flatnonzero(ok)))
            d_m = _bilinear(ndf32.astype(float), um[ok])
            sig = float(_bilinear(sigma32.astype(float), np.array([_theta2u(t), (phi + np.pi) / (2 * np.pi)])))
            factor.append(wo[ok, 2] * 4 * sig / np.maximum(d_m, 1e-30))
    values = f_r(np.concatenate(pairs_i), np.concatenate(pairs_o))
    n_bands = values.shape[1]
    if wl is not None and n_bands != wl.size:
        raise ExportError(f"the source gives {n_bands} bands for {wl.size} wavelengths")
    if wl is None and n_bands != 3:
        raise ExportError(f"an RGB export needs 3 channels (R, G, B); the source gives {n_bands}")
    table = np.zeros((phis.size, nodes.size, n_bands, res * res))
    start = 0
    for (p, j, idx), fac in zip(where, factor, strict=True):
        table[p, j][:, idx] = (np.clip(values[start:start + idx.size], 0, None) * fac[:, None]).T
        start += idx.size
    table = table.reshape(phis.size, nodes.size, n_bands, res, res)
    lum = np.einsum("pjbyx,b->pjyx", table, ylum)
    text = description.encode("utf-8")
    fields: dict[str, np.ndarray] = {
        "description": np.frombuffer(text, np.uint8).copy() if text else np.zeros(1, np.uint8),
        "version": np.array([1, 0], np.uint32),
        "phi_i": phis.astype(np.float32),
        "theta_i": nodes.astype(np.float32),
        "ndf": ndf32,
        "sigma": sigma32,
        "vndf": vndf,
        "luminance": lum.astype(np.float32),
        "jacobian": np.ones(1, np.uint8),
        "valid": np.packbits(valid.ravel()),
    }
    if wl is None:
        fields["rgb"] = table.astype(np.float32)
    else:
        fields["spectra"] = table.astype(np.float32)
        fields["wavelengths"] = wl.astype(np.float32)
    if provenance:
        fields["provenance"] = np.frombuffer(json.dumps(provenance, default=str).encode(), np.uint8).copy()
    return fields, evaluations


def random_pairs(rng: np.random.Generator, n: int, theta_max_deg: float = 80.0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` direction pairs, each uniform over the solid angle of the cap ``theta <= theta_max``."""
    cmin = np.cos(np.radians(theta_max_deg))
    out = []
    for _ in range(2):
        z = rng.uniform(cmin, 1.0, n)
        p = rng.uniform(0, 2 * np.pi, n)
        r = np.sqrt(1 - z * z)
        out.append(np.stack([r * np.cos(p), r * np.sin(p), z], axis=-1))
    return out[0], out[1]


def tabulation_error(brdf: BRDF, fields_or_path: dict | str | os.PathLike, *, n_pairs: int = 2000,
                     seed: int = 0, theta_max_deg: float = 80.0,
                     azimuths_deg: Sequence[float] = (0.0,)) -> dict[str, Any]:
    """Relative error of the tabulated ``beta`` against ``brdf`` at random pairs (RMS, max, p95).

    The source is averaged over ``azimuths_deg`` as the export did; values where the source's
    ``beta`` is below 1e-6 of its largest are left out of the relative error.
    """
    from gonio.data.formats.rgl_bsdf import RGLBSDF, read_rgl_bsdf

    tab = (RGLBSDF(fields_or_path, "<memory>") if isinstance(fields_or_path, dict)
           else read_rgl_bsdf(fields_or_path))
    wi, wo = random_pairs(np.random.default_rng(seed), n_pairs, theta_max_deg)
    got = np.pi * tab.eval_cos(wi, wo) / wo[:, 2:]
    ref = np.zeros_like(got)
    for a in np.radians(np.asarray(azimuths_deg, float)):
        c, s = np.cos(a), np.sin(a)
        rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
        ref = ref + np.asarray(brdf(wi @ rz.T, wo @ rz.T), float).reshape(got.shape)
    ref = ref / len(azimuths_deg)
    ok = ref > 1e-6 * np.max(ref)
    rel = np.abs(got[ok] - ref[ok]) / ref[ok]
    return {"pairs": int(n_pairs), "seed": int(seed), "theta_max_deg": float(theta_max_deg),
            "rms": float(np.sqrt(np.mean(rel ** 2))), "max": float(rel.max()),
            "p95": float(np.quantile(rel, 0.95))}


def export_bsdf(brdf: BRDF, out: str | os.PathLike, *, wavelengths_nm: npt.ArrayLike | None = None,
                theta_i_deg: npt.ArrayLike | None = None, res: int = 64,
                azimuths_deg: Sequence[float] = (0.0,), description: str = "",
                provenance: dict | None = None, check_pairs: int = 0, seed: int = 0,
                n_retro: int = 32, reduction: int = 0, n_phi_i: int = 5) -> ExportResult:
    """Tabulate ``brdf`` (see the module docstring) and write the ``.bsdf`` file ``out``.

    ``check_pairs > 0``: measure the tabulation error at that many random pairs first (more
    evaluations of the source) and record it in the file's ``provenance`` field.
    """
    prov = dict(provenance or {})
    prov.update({"writer": "gonio.data.bsdf_export", "isotropic": not reduction, "retro_samples": n_retro,
                 "value_resolution": res})
    if reduction:
        prov.update({"reduction": reduction, "incidence_azimuths": n_phi_i})
        azimuths_deg = (0.0,)
    else:
        prov["azimuths_averaged_deg"] = [float(a) for a in azimuths_deg]
    fields, n_eval = build_fields(brdf, wavelengths_nm=wavelengths_nm, theta_i_deg=theta_i_deg,
                                  res=res, azimuths_deg=azimuths_deg, description=description,
                                  provenance=prov, n_retro=n_retro, reduction=reduction, n_phi_i=n_phi_i)
    err = None
    if check_pairs > 0:
        err = tabulation_error(brdf, fields, n_pairs=check_pairs, seed=seed, azimuths_deg=azimuths_deg)
        prov["tabulation_error"] = err
        fields["provenance"] = np.frombuffer(json.dumps(prov, default=str).encode(), np.uint8).copy()
    try:
        write_tensor_file(out, fields)   # atomic: a failed write leaves no file and no temporary file
    except OSError as exc:
        raise ExportError(f"{out}: cannot write ({exc.strerror or exc}); no file was written (an existing one is "
                          "unchanged): free space or choose another --out") from None
    valid = np.unpackbits(fields["valid"])
    return ExportResult(str(out), fields, n_eval, float(valid.mean()), err, prov)
