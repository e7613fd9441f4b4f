"""Export a BRDF as an RGL ``.bsdf`` file (Dupuy & Jakob 2018), isotropic, RGB or spectral.

What renderers read: Mitsuba 3's ``measured`` plugin and pbrt-v4's ``measured`` material; the
project's own reader is :mod:`gonio.data.formats.rgl_bsdf` (``gonio import rgl-bsdf``). The
source is any *BRDF callable* ``beta(w_i, w_o) -> (N, bands)`` (the radiance coefficient
``beta = pi f_r`` at unit fabric-frame directions ``(N, 3)``): a fabric model evaluated on demand
(:mod:`simulate.export`) or a measured dataset (:func:`dataset_brdf`). Only the direction pairs
the tensor needs are asked for, in two batches:

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

Incidence nodes: ``theta_i`` in 0..90 deg (default 16, uniform in ``cos(theta_i)``: dense towards
grazing, where the specular lobe and Fresnel change fastest); the 90 deg node holds the
model's values at :data:`GRAZING_EVAL_DEG` (models refuse ``cos(theta_i) = 0``). Anisotropic
sources are exported isotropically: the values are averaged over the azimuths ``azimuths_deg``
of the incidence (stated in the description and provenance).

Tabulation error, measured (defaults: 16 incidences, 64 x 64 values; relative error of ``beta``
read back with the project's reader, i.e. Mitsuba's numerics, against the source at 4000 random
direction pairs, seed 0, each direction uniform over the cap ``theta <= theta_max``)::

    source                                theta_max   RMS      p95     max
    classic model, red-cotton, 3 bands    60 deg      0.38 %   0.72 %  5.3 %
                                          80 deg      0.88 %   1.4 %   33 %
    Lambertian (RGB)                      60 deg      0.66 %   1.5 %   7.4 %
                                          80 deg      0.79 %   1.3 %   14 %

The largest errors sit near the mirror direction at large incidence (half vectors near the
normal, which the ``u = sqrt(2 theta / pi)`` warp with its ``u sin(theta_m)`` Jacobian resolves
coarsely for a broad NDF) and, for the classic model, in the grazing forward Fresnel peak of its
darkest band. 32 x 32 values and 10 incidences (the RGL files' size) give RMS 1-4 % and maxima
above 100 % there. :data:`STATED_TABULATION_ERROR` is the bound the tests hold exports to.
(A narrow lobe mixed into the warping NDF to resolve the normal better was tried and made the
grazing errors worse; not used.)

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
import os
import struct
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import numpy.typing as npt

from gonio.data.dataset import DatasetError, atomic_write

__all__ = ["BRDF", "ExportError", "ExportResult", "STATED_TABULATION_ERROR", "build_fields",
           "dataset_brdf", "export_bsdf", "incidence_nodes", "tabulation_error", "write_tensor_file"]

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
_DTYPE_CODES = {np.dtype(np.uint8): 1, np.dtype(np.uint32): 5, np.dtype(np.float32): 10}


class ExportError(DatasetError):
    """A source that cannot be exported (one line: what and what to do)."""


@dataclass
class ExportResult:
    path: str
    fields: dict[str, np.ndarray]
    evaluations: int
    valid_fraction: float
    error: dict[str, Any] | None = None
    provenance: dict[str, Any] = field(default_factory=dict)


def write_tensor_file(path: str | os.PathLike, fields: dict[str, np.ndarray]) -> None:
    """Write Mitsuba's ``tensor_file`` (little-endian, version 1.0), atomically.

    Header: ``tensor_file\\0``, version bytes ``1, 0``, field count (uint32); per field the name
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
    for (name, a), off in zip(items, offsets):
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


def _vndf_table(d_nodes: np.ndarray, theta_i: float, res: tuple[int, int] = (128, 128)) -> np.ndarray:
    """``D(m) <w_i, m>+ u sin(theta_m)`` on the ``(u_phi rows, u_theta columns)`` grid, phi_i = 0."""
    h, w = res
    ux = np.linspace(0, 1, w)
    uy = np.linspace(0, 1, h)
    tm = _u2theta(ux)[None, :]
    pm = ((2 * uy - 1) * np.pi)[:, None]
    dot = np.sin(theta_i) * np.sin(tm) * np.cos(pm) + np.cos(theta_i) * np.cos(tm)
    d = np.interp(ux, np.linspace(0, 1, d_nodes.size), d_nodes)[None, :]
    return d * np.clip(dot, 0, None) * ux[None, :] * np.sin(tm)


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


def build_fields(brdf: BRDF, *, wavelengths_nm: npt.ArrayLike | None = None,
                 theta_i_deg: npt.ArrayLike | None = None, res: int = 64,
                 azimuths_deg: Sequence[float] = (0.0,), description: str = "",
                 provenance: dict | None = None, n_retro: int = 32) -> tuple[dict[str, np.ndarray], int]:
    """The tensor fields of ``brdf`` (spectral when ``wavelengths_nm`` is given, else RGB).

    Returns the fields and the number of direction pairs the source was evaluated at.
    """
    wl = None if wavelengths_nm is None else np.asarray(wavelengths_nm, float)
    ylum = _luminance_weights(wl)
    nodes = np.radians(np.asarray(theta_i_deg if theta_i_deg is not None else incidence_nodes(16), float))
    if nodes.size < 2 or nodes[0] != 0 or abs(nodes[-1] - np.pi / 2) > 1e-9 or np.any(np.diff(nodes) <= 0):
        raise ExportError("incidence nodes must increase from 0 to 90 deg (at least 2)")
    if res < 4:
        raise ExportError(f"value resolution {res} is too small (at least 4)")
    rot = np.radians(np.asarray(azimuths_deg, float))
    evaluations = 0

    def f_r(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``f_r`` averaged over the rotations of the pair about the normal: ``(N, bands)``."""
        nonlocal evaluations
        total = None
        for a in rot:
            c, s = np.cos(a), np.sin(a)
            rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
            b = np.asarray(brdf(wi @ rz.T, wo @ rz.T), float).reshape(wi.shape[0], -1)
            evaluations += wi.shape[0]
            total = b if total is None else total + b
        assert total is not None
        return np.nan_to_num(total / rot.size / np.pi, nan=0.0)

    def retro_y(theta: np.ndarray) -> np.ndarray:
        w = _hemisphere_dirs(theta, 0.0)
        return f_r(w, w) @ ylum

    ndf, sigma = fit_ndf(retro_y, n_retro=n_retro)
    u_nodes = np.linspace(0, 1, ndf.size)
    ndf32, sigma32 = ndf.astype(np.float32), sigma.astype(np.float32)
    vndf = np.stack([_vndf_table(ndf, t) for t in nodes])[None].astype(np.float32)
    g = (np.arange(res) + 0.0) / (res - 1)
    sx, sy = np.meshgrid(g, g)                       # rows: s_y, columns: s_x
    s = np.stack([sx.ravel(), sy.ravel()], axis=-1)
    pairs_i, pairs_o, where, factor = [], [], [], []
    valid = np.zeros((1, nodes.size, res, res), bool)
    for j, t in enumerate(nodes):
        um = warp_forward(vndf[0, j].astype(float), s)
        m = _hemisphere_dirs(_u2theta(um[:, 0]), (2 * um[:, 1] - 1) * np.pi)
        wi = _hemisphere_dirs(t, 0.0)
        wo = 2 * (m @ wi)[:, None] * m - wi
        ok = wo[:, 2] > 1e-6
        valid[0, j] = ok.reshape(res, res)
        t_eval = min(t, np.radians(GRAZING_EVAL_DEG))
        pairs_i.append(np.broadcast_to(_hemisphere_dirs(t_eval, 0.0), (int(ok.sum()), 3)))
        pairs_o.append(wo[ok] / np.linalg.norm(wo[ok], axis=-1, keepdims=True))
        where.append((j, np.flatnonzero(ok)))
        d_m = np.interp(um[ok, 0], u_nodes, ndf32.astype(float))
        sig = float(np.interp(_theta2u(t), u_nodes, sigma32.astype(float)))
        factor.append(wo[ok, 2] * 4 * sig / np.maximum(d_m, 1e-30))
    values = f_r(np.concatenate(pairs_i), np.concatenate(pairs_o))
    n_bands = values.shape[1]
    if wl is not None and n_bands != wl.size:
        raise ExportError(f"the source gives {n_bands} bands for {wl.size} wavelengths")
    if wl is None and n_bands != 3:
        raise ExportError(f"an RGB export needs 3 channels (R, G, B); the source gives {n_bands}")
    table = np.zeros((1, nodes.size, n_bands, res * res))
    start = 0
    for (j, idx), fac in zip(where, factor):
        table[0, j][:, idx] = (np.clip(values[start:start + idx.size], 0, None) * fac[:, None]).T
        start += idx.size
    table = table.reshape(1, nodes.size, n_bands, res, res)
    lum = np.einsum("pjbyx,b->pjyx", table, ylum)
    text = description.encode("utf-8")
    fields: dict[str, np.ndarray] = {
        "description": np.frombuffer(text, np.uint8).copy() if text else np.zeros(1, np.uint8),
        "version": np.array([1, 0], np.uint32),
        "phi_i": np.zeros(1, np.float32),
        "theta_i": nodes.astype(np.float32),
        "ndf": np.stack([ndf32, ndf32]),
        "sigma": np.stack([sigma32, sigma32]),
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
                n_retro: int = 32) -> ExportResult:
    """Tabulate ``brdf`` (see the module docstring) and write the ``.bsdf`` file ``out``.

    ``check_pairs > 0``: measure the tabulation error at that many random pairs first (more
    evaluations of the source) and record it in the file's ``provenance`` field.
    """
    prov = dict(provenance or {})
    prov.update({"writer": "gonio.data.bsdf_export", "isotropic": True, "retro_samples": n_retro,
                 "azimuths_averaged_deg": [float(a) for a in azimuths_deg], "value_resolution": res})
    fields, n_eval = build_fields(brdf, wavelengths_nm=wavelengths_nm, theta_i_deg=theta_i_deg,
                                  res=res, azimuths_deg=azimuths_deg, description=description,
                                  provenance=prov, n_retro=n_retro)
    err = None
    if check_pairs > 0:
        err = tabulation_error(brdf, fields, n_pairs=check_pairs, seed=seed, azimuths_deg=azimuths_deg)
        prov["tabulation_error"] = err
        fields["provenance"] = np.frombuffer(json.dumps(prov, default=str).encode(), np.uint8).copy()
    write_tensor_file(out, fields)
    valid = np.unpackbits(fields["valid"])
    return ExportResult(str(out), fields, n_eval, float(valid.mean()), err, prov)


def dataset_brdf(dataset: Any) -> tuple[BRDF, dict[str, Any]]:
    """A measured dataset's in-plane curves as a BRDF callable, with the coverage rule stated.

    Rule for the directions a measurement does not cover (``valid`` says nothing about it; the
    returned dict and the export's provenance do): the in-plane curves ``beta(theta_i, s)`` are
    interpolated linearly in ``theta_i`` and ``s``, clamped to the measured ranges of both (nearest
    curve end); a pair with relative azimuth ``dphi`` between the curves is the blend
    ``(1 + cos dphi)/2 beta(theta_i, -theta_o) + (1 - cos dphi)/2 beta(theta_i, +theta_o)``
    (source side to mirror side). Refused: fewer than 2 incidences or fewer than 3 observation
    angles on either side of an incidence, RGB data other than R, G, B, relative (raw) units,
    geometries missing some of the bands.
    """
    from scipy.interpolate import RegularGridInterpolator

    from gonio.data.geometry import signed_angle

    name = getattr(dataset, "source", None) or "dataset"
    if getattr(dataset, "relative", False):
        raise ExportError(f"{name}: relative (raw-unit) values cannot be exported as a BRDF; "
                          "import it with an absolute scale or a white standard first")
    t = dataset.table
    band_col = dataset.band_column
    bands = list(dataset.bands)
    if dataset.is_rgb and bands != ["R", "G", "B"]:
        raise ExportError(f"{name}: channels {','.join(bands)} - an RGB export needs exactly R, G, B")
    s = signed_angle(t["theta_i"].to_numpy(float), t["phi_i"].to_numpy(float),
                     t["theta_o"].to_numpy(float), t["phi_o"].to_numpy(float))
    inplane = t[np.isfinite(s)].assign(s=s[np.isfinite(s)])
    pivot = inplane.pivot_table(index=["theta_i", "s"], columns=band_col, values="beta",
                                aggfunc="mean").reindex(columns=bands)
    if pivot.isna().to_numpy().any():
        raise ExportError(f"{name}: some geometries lack some of the bands "
                          f"({'channels' if dataset.is_rgb else 'wavelengths'} mixed); cannot tabulate")
    incid = np.unique(pivot.index.get_level_values(0))
    if incid.size < 2:
        raise ExportError(f"{name}: {incid.size} in-plane incidence angle(s); an export needs at "
                          "least 2 (the tensor spans 0..90 deg of incidence)")
    grids = []
    for ti in incid:
        sv = pivot.loc[ti].index.to_numpy(float)
        if np.sum(sv < 0) < 3 or np.sum(sv > 0) < 3:
            raise ExportError(f"{name}: incidence {ti:g} deg has fewer than 3 observation angles on "
                              "one side of the normal; cannot interpolate its curve")
        grids.append(sv)
    s_all = np.unique(np.concatenate(grids))
    s_lo, s_hi = max(g.min() for g in grids), min(g.max() for g in grids)
    s_grid = s_all[(s_all >= s_lo) & (s_all <= s_hi)]
    cube = np.stack([np.stack([np.interp(s_grid, pivot.loc[ti].index.to_numpy(float),
                                         pivot.loc[ti][b].to_numpy(float)) for b in bands], -1)
                     for ti in incid])
    interp = RegularGridInterpolator((incid, s_grid), cube, method="linear")

    def beta(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        ti = np.degrees(np.arccos(np.clip(wi[:, 2], -1, 1)))
        to = np.degrees(np.arccos(np.clip(wo[:, 2], -1, 1)))
        dphi = np.arctan2(wo[:, 1], wo[:, 0]) - np.arctan2(wi[:, 1], wi[:, 0])
        tc = np.clip(ti, incid[0], incid[-1])
        back = interp(np.stack([tc, np.clip(-to, s_grid[0], s_grid[-1])], -1))
        fwd = interp(np.stack([tc, np.clip(to, s_grid[0], s_grid[-1])], -1))
        w = ((1 - np.cos(dphi)) / 2)[:, None]
        return (1 - w) * back + w * fwd

    rule = {"source": "measured dataset (in-plane curves)",
            "incidences_deg": incid.tolist(), "observation_range_deg": [float(s_lo), float(s_hi)],
            "rule": "linear in theta_i and s, clamped to the measured ranges; out-of-plane by the "
                    "(1 +- cos dphi)/2 blend of the source-side and mirror-side curves",
            "extrapolated": "every incidence outside the measured range and every out-of-plane pair"}
    return beta, rule
