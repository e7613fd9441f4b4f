r"""RGL ``.bsdf`` files (EPFL material database; Dupuy & Jakob 2018): reading and evaluation.

A file stores a BRDF in the *adaptive parameterisation* of Dupuy & Jakob: for each incidence
``(phi_i, theta_i)`` a 2D table over the unit square ``u = (u_theta, u_phi)`` of the half vector
``m`` (``theta_m = u_theta^2 pi/2``, ``phi_m = (2 u_phi - 1) pi``, relative to ``phi_i`` for
isotropic materials), warped by the visible normal distribution (``vndf``); the measured values
(``rgb`` or ``spectra``) are tabulated over the *warped* square. Evaluation at ``(w_i, w_o)``:

.. math::

    m = \frac{w_i + w_o}{|w_i + w_o|}, \quad
    s = \mathrm{VNDF}^{-1}(u(m) \mid \phi_i, \theta_i), \quad
    f_r \cos\theta_o = S(s \mid \phi_i, \theta_i, \lambda)\,
        \frac{D(u(m))}{4\,\sigma(u(w_i))}

where ``VNDF^{-1}`` is the inverse of the continuous marginal/conditional sample warp of a
bilinearly interpolated table (the incidence parameters interpolated linearly), ``D`` the NDF
and ``sigma`` the projected area table (the last factor only when the file's ``jacobian`` flag
is set). The stored quantity is ``f_r cos theta_o`` (Mitsuba's BSDF ``eval`` convention), so the
radiance coefficient is ``beta = pi f_r = pi S D / (4 sigma cos theta_o)``. Everything is
vectorised over arrays of direction pairs.

This is a numpy transcription of Mitsuba 3's ``measured`` plugin (``src/bsdfs/measured.cpp``) and
its ``Marginal2D`` warp (``include/mitsuba/core/distr_2d.h``, continuous case); the tests compare
it with Mitsuba 3 itself at random direction pairs.

References
----------
J. Dupuy, W. Jakob, "An Adaptive Parameterization for Efficient Material Acquisition and
Rendering", ACM Trans. Graph. 37(6), 2018. Mitsuba 3 (W. Jakob et al.), ``measured`` BSDF.
RGL material database, https://rgl.epfl.ch/materials (CC0).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from gonio.data.formats.errors import FormatError
from gonio.data.formats.tensor import TensorHeader, read_tensor_file

__all__ = ["RGLBSDF", "read_rgl_bsdf", "incidence_meta", "MAX_ANGLES", "MAX_ROWS"]

_REQUIRED = ("theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance", "description", "jacobian")
#: Most incidence angles per axis (``theta_i``, ``phi_i``) read; the RGL files hold about ten.
MAX_ANGLES = 1024
#: Most rows (geometries x bands) of a converted dataset (about 200 MB as a table).
MAX_ROWS = 2_000_000
#: Geometries evaluated per chunk (bounds the evaluation's temporary arrays).
_CHUNK = 1 << 16


class _Marginal2D:
    """Mitsuba's continuous ``Marginal2D``: a bilinear table with linear parameter interpolation.

    ``data`` has shape ``(*param_res, H, W)``; positions are ``(x, y)`` in the unit square with
    ``x`` along the last axis (``W`` columns).
    """

    def __init__(self, data: np.ndarray, params: Sequence[np.ndarray], *, normalize: bool = True,
                 sampling: bool = True):
        data = np.asarray(data, dtype=np.float64)
        self.params = [np.asarray(p, dtype=np.float64) for p in params]
        self.size = np.array([data.shape[-1], data.shape[-2]])   # (W, H)
        w, h = int(self.size[0]), int(self.size[1])
        self.normalized = normalize
        if sampling:
            scale_x, scale_y = 0.5 / (w - 1), 0.5 / (h - 1)
            cond = np.cumsum(scale_x * (data[..., :, :-1] + data[..., :, 1:]), axis=-1)
            row_sum = cond[..., -1]
            marg = np.cumsum(scale_y * (row_sum[..., :-1] + row_sum[..., 1:]), axis=-1)
            norm = 1.0 / marg[..., -1] if normalize else np.ones(marg.shape[:-1])
            self.cond = cond * norm[..., None, None]
            self.marg = marg * norm[..., None]
            data = data * norm[..., None, None]
        elif normalize:
            raise ValueError("normalisation without sampling tables is not used here")
        self.data = data

    def _weights(self, param: Sequence[np.ndarray]):
        """Per parameter: (index of the lower node, weight of the upper node)."""
        out = []
        for values, p in zip(self.params, param, strict=True):
            if values.size == 1:
                out.append((np.zeros(np.shape(p), dtype=np.intp), np.zeros(np.shape(p))))
                continue
            idx = np.clip(np.searchsorted(values, p, side="left") - 1, 0, values.size - 2)
            p0, p1 = values[idx], values[idx + 1]
            out.append((idx, np.clip((p - p0) / (p1 - p0), 0.0, 1.0)))
        return out

    def _lookup(self, table: np.ndarray, weights, *rest: np.ndarray) -> np.ndarray:
        """``table[params..., *rest]`` linearly interpolated over the parameters."""
        total: np.ndarray = np.zeros(())
        dims = len(weights)
        for corner in range(1 << dims):
            w = 1.0
            index = []
            for d, (idx, w1) in enumerate(weights):
                upper = (corner >> d) & 1
                n = table.shape[d]
                index.append(np.minimum(idx + upper, n - 1))
                w = w * (w1 if upper else 1.0 - w1)
            total = total + w * table[tuple(index) + tuple(rest)]
        return total

    def eval(self, pos: np.ndarray, param: Sequence[np.ndarray] = ()) -> np.ndarray:
        weights = self._weights(param)
        pos = np.clip(pos, 0.0, 1.0) * (self.size - 1)
        offset = np.minimum(pos.astype(np.intp), self.size - 2)
        frac = pos - offset
        ox, oy = offset[..., 0], offset[..., 1]
        v00 = self._lookup(self.data, weights, oy, ox)
        v10 = self._lookup(self.data, weights, oy, ox + 1)
        v01 = self._lookup(self.data, weights, oy + 1, ox)
        v11 = self._lookup(self.data, weights, oy + 1, ox + 1)
        fx, fy = frac[..., 0], frac[..., 1]
        return (1 - fy) * ((1 - fx) * v00 + fx * v10) + fy * ((1 - fx) * v01 + fx * v11)

    def invert(self, sample: np.ndarray, param: Sequence[np.ndarray] = ()) -> np.ndarray:
        """Inverse of the sample warp: a position in the table -> the uniform sample."""
        weights = self._weights(param)
        w = int(self.size[0])
        sample = np.clip(sample, 0.0, 1.0) * (self.size - 1)
        pos = np.minimum(sample.astype(np.intp), self.size - 2)
        sample = sample - pos
        px, py = pos[..., 0], pos[..., 1]
        sx, sy = sample[..., 0], sample[..., 1]
        v00 = self._lookup(self.data, weights, py, px)
        v10 = self._lookup(self.data, weights, py, px + 1)
        v01 = self._lookup(self.data, weights, py + 1, px)
        v11 = self._lookup(self.data, weights, py + 1, px + 1)
        c0 = v00 + (v01 - v00) * sy
        c1 = v10 + (v11 - v10) * sy
        patch_x, patch_y = 1.0 / (self.size[0] - 1), 1.0 / (self.size[1] - 1)
        x = sx * (c0 + (c1 - c0) * 0.5 * sx) * patch_x
        prev = np.maximum(px - 1, 0)
        cond_prev = (self._lookup(self.cond, weights, py, prev) * (1 - sy)
                     + self._lookup(self.cond, weights, py + 1, prev) * sy)
        x = x + np.where(px > 0, cond_prev, 0.0)
        r0 = self._lookup(self.cond, weights, py, np.full_like(px, w - 2))
        r1 = self._lookup(self.cond, weights, py + 1, np.full_like(px, w - 2))
        x = x / (r0 + (r1 - r0) * sy)
        y = sy * (r0 + (r1 - r0) * 0.5 * sy) * patch_y
        marg_prev = self._lookup(self.marg, weights, np.maximum(py - 1, 0))
        y = y + np.where(py > 0, marg_prev, 0.0)
        if not self.normalized:
            y = y / self._lookup(self.marg, weights, np.full_like(py, self.marg.shape[-1] - 1))
        return np.stack([x, y], axis=-1)


def _elevation(d: np.ndarray) -> np.ndarray:
    """``acos(d_z)`` computed as ``2 asin(|d - z| / 2)`` (accurate near the pole)."""
    dist = np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + (d[..., 2] - 1.0) ** 2)
    return 2.0 * np.arcsin(np.clip(0.5 * dist, 0.0, 1.0))


def _theta2u(theta):
    return np.sqrt(theta * (2.0 / np.pi))


def _phi2u(phi):
    return (phi + np.pi) * (0.5 / np.pi)


class RGLBSDF:
    """A BRDF read from an RGL ``.bsdf`` file, evaluated in vectorised numpy.

    Attributes
    ----------
    description : str
        The file's own description of the material.
    is_spectral : bool
        True for spectral files (``wavelengths_nm`` set), False for RGB ones (channels R, G, B).
    isotropic : bool
    theta_i_deg : numpy.ndarray
        The incidence angles the file was measured at.
    """

    def __init__(self, fields: dict[str, np.ndarray], path: str | os.PathLike = "<bsdf>"):
        self.path = str(path)
        _check_structure(fields, self.path)
        self.is_spectral = "wavelengths" in fields
        spectra = fields["spectra"] if self.is_spectral else fields["rgb"]
        wavelengths = np.asarray(fields["wavelengths"], dtype=float) if self.is_spectral else None
        self.wavelengths_nm = wavelengths
        #: the tables' band coordinate: the wavelengths, or the channels' indices 0, 1, 2
        self._bands = wavelengths if wavelengths is not None else np.arange(3.0)
        bands = self._bands
        phi_i = np.asarray(fields["phi_i"], dtype=float)
        theta_i = np.asarray(fields["theta_i"], dtype=float)
        self.isotropic = phi_i.size <= 2
        self.jacobian = bool(fields["jacobian"][0])
        self.reduction = 0
        if not self.isotropic:
            self.reduction = int(np.rint(2 * np.pi / (phi_i[-1] - phi_i[0])))
        labels = list(self.channels) if not self.is_spectral else [f"{w:g} nm" for w in bands]
        #: per band (channel or wavelength label): (negative stored values, stored values)
        self.negative_values = {label: (int(np.count_nonzero(spectra[:, :, k] < 0)),
                                        int(spectra[:, :, k].size))
                                for k, label in enumerate(labels)
                                if np.any(spectra[:, :, k] < 0)}
        self.description = bytes(fields["description"]).decode("utf-8", errors="replace")
        self.theta_i_deg = np.degrees(theta_i)
        self.phi_i_deg = np.degrees(phi_i)
        self._ndf = _Marginal2D(fields["ndf"], (), normalize=False, sampling=False)
        self._sigma = _Marginal2D(fields["sigma"], (), normalize=False, sampling=False)
        self._vndf = _Marginal2D(fields["vndf"], (phi_i, theta_i))
        self._spectra = _Marginal2D(spectra, (phi_i, theta_i, bands), normalize=False,
                                    sampling=False)
        self._n_bands = bands.size

    @property
    def channels(self) -> tuple[str, ...]:
        """``("R", "G", "B")`` for an RGB file, ``()`` for a spectral one."""
        return () if self.is_spectral else ("R", "G", "B")

    def eval_cos(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``f_r cos theta_o`` for unit vectors ``wi``, ``wo`` (``(..., 3)``): ``(..., bands)``.

        Zero where either direction is below the surface (as Mitsuba's ``eval``).
        """
        wi = np.array(wi, dtype=float, copy=True)
        wo = np.array(wo, dtype=float, copy=True)
        wi, wo = np.broadcast_arrays(wi, wo)
        wi, wo = wi.copy(), wo.copy()
        active = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        if self.reduction >= 2:
            sy = wi[..., 1].copy()
            sx = wi[..., 0].copy() if self.reduction == 4 else sy
            for w in (wi, wo):   # drjit mulsign_neg(a, b) = a * -sign(b), sign(0) = +1
                w[..., 0] = np.where(sx >= 0, -w[..., 0], w[..., 0])
                w[..., 1] = np.where(sy >= 0, -w[..., 1], w[..., 1])
        m = wi + wo
        m = m / np.maximum(np.linalg.norm(m, axis=-1, keepdims=True), 1e-300)
        theta_i = _elevation(wi)
        phi_i = np.arctan2(wi[..., 1], wi[..., 0])
        theta_m = _elevation(m)
        phi_m = np.arctan2(m[..., 1], m[..., 0])
        u_wi = np.stack([_theta2u(theta_i), _phi2u(phi_i)], axis=-1)
        u_m1 = _phi2u(phi_m - phi_i if self.isotropic else phi_m)
        u_m = np.stack([_theta2u(theta_m), u_m1 - np.floor(u_m1)], axis=-1)
        params = (phi_i, theta_i)
        with np.errstate(divide="ignore", invalid="ignore"):     # a zero row: NaN, refused just below
            sample = self._vndf.invert(u_m, params)
        lost = ~np.all(np.isfinite(sample), axis=-1)
        if np.any(lost & active):
            # the warp divides by the table row's mass: a row of zeros where the incidence's visible normals
            # must be (a table copied from another incidence) leaves no position to look the values up at
            where = ", ".join(f"{t:.4g}" for t in np.unique(np.round(np.degrees(theta_i[lost & active]), 2))[:5])
            raise FormatError(f"field 'vndf' has no visible normal where directions at incidence {where} deg "
                              "need one (rows of zeros in its table there)", file=self.path,
                              hint="not a consistent RGL .bsdf file: each incidence's vndf table must cover "
                                   "its visible normals")
        sample = np.where(lost[..., None], 0.0, sample)
        out = np.empty(wi.shape[:-1] + (self._n_bands,))
        bands = self._bands
        for k in range(self._n_bands):
            out[..., k] = self._spectra.eval(sample, (phi_i, theta_i, np.full(phi_i.shape, bands[k])))
        if self.jacobian:
            factor = self._ndf.eval(u_m) / (4.0 * self._sigma.eval(u_wi))
            out *= factor[..., None]
        return np.where(active[..., None], out, 0.0)

    def beta(self, theta_i, phi_i, theta_o, phi_o) -> np.ndarray:
        """Radiance coefficient ``beta = pi f_r`` at fabric-frame angles (degrees): ``(..., bands)``.

        The file's value is ``f_r cos theta_o``: divided here by ``cos theta_o``. At
        ``theta_o = 90`` (grazing) ``beta`` is returned as 0 (the stored value vanishes there).
        """
        from gonio.data.geometry import direction

        wi = direction(theta_i, phi_i)
        wo = direction(theta_o, phi_o)
        wi, wo = np.broadcast_arrays(wi, wo)
        value = np.empty(wi.shape[:-1] + (self._n_bands,))
        flat_v = value.reshape(-1, self._n_bands)
        flat_i, flat_o = wi.reshape(-1, 3), wo.reshape(-1, 3)
        chunk = max(1, _CHUNK * 3 // self._n_bands)     # bounded temporaries, any band count
        for k in range(0, flat_i.shape[0], chunk):
            flat_v[k:k + chunk] = self.eval_cos(flat_i[k:k + chunk], flat_o[k:k + chunk])
        cos_o = wo[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            beta = np.where(cos_o[..., None] > 1e-9, np.pi * value / cos_o[..., None], 0.0)
        return beta

    def _negative_provenance(self, beta: np.ndarray) -> dict[str, Any]:
        """``{"negative_values": {band: {"stored", "of", "rows"}}}`` when the file has any."""
        if not self.negative_values:
            return {}
        out = {}
        for k, label in enumerate(_labels(self)):
            if label in self.negative_values:
                n, total = self.negative_values[label]
                out[label] = {"stored": n, "of": total,
                              "rows": int(np.count_nonzero(beta[:, k] < 0))}
        return {"negative_values": out}

    def to_dataset(self, geometries: pd.DataFrame | None = None, *, s_step_deg: float = 2.0,
                   s_max_deg: float = 80.0, provenance: dict[str, Any] | None = None):
        """A radiance-coefficient dataset (kind "measured") at ``geometries``.

        ``geometries`` has columns ``theta_i, phi_i, theta_o, phi_o`` (degrees); by default the
        in-plane curves at the file's own incidence angles, ``phi_i = 0``, signed observation
        angles ``-s_max..s_max`` every ``s_step`` degrees. ``u_beta`` is 0 and ``n`` 1: the file
        carries no uncertainty.
        """
        from gonio.data.dataset import make_dataset, new_meta
        from gonio.data.geometry import in_plane_geometry

        if geometries is None:
            s = np.arange(-s_max_deg, s_max_deg + 1e-9, s_step_deg)
            ti = np.repeat(self.theta_i_deg, s.size)
            ss = np.tile(s, self.theta_i_deg.size)
            to, po = in_plane_geometry(ti, ss, 0.0)
            geometries = pd.DataFrame({"theta_i": ti, "phi_i": 0.0, "theta_o": to, "phi_o": po})
        geo = geometries[["theta_i", "phi_i", "theta_o", "phi_o"]].drop_duplicates()
        if len(geo) * self._n_bands > MAX_ROWS:
            raise FormatError(f"{len(geo)} geometries x {self._n_bands} bands is "
                              f"{len(geo) * self._n_bands} rows, more than {MAX_ROWS}",
                              file=self.path, hint="evaluate at fewer geometries (--plan)")
        beta = self.beta(*(geo[c].to_numpy(dtype=float) for c in ("theta_i", "phi_i", "theta_o",
                                                                   "phi_o")))
        rows = []
        labels = list(self.channels) if self.wavelengths_nm is None else list(self.wavelengths_nm)
        band = "wavelength_nm" if self.is_spectral else "channel"
        for k, label in enumerate(labels):
            part = geo.copy()
            part[band] = label
            part["beta"] = beta[:, k]
            part["u_beta"] = 0.0
            part["n"] = 1
            rows.append(part)
        table = pd.concat(rows, ignore_index=True)
        name = Path(self.path).stem
        incidences = incidence_meta(self.theta_i_deg, geo["theta_i"].to_numpy(float), Path(self.path).name)
        meta = new_meta("measured", {"name": name, "description": self.description, "incidences": incidences},
                        {"name": "RGL gonio-photometer (EPFL), adaptive parameterisation",
                         "format": "rgl-bsdf"},
                        {"source_file": Path(self.path).name,
                         "converted_by": "gonio.data.formats.rgl_bsdf (numpy transcription of "
                                         "Mitsuba 3's measured plugin)",
                         "beta": "pi * (stored f_r cos theta_o) / cos theta_o",
                         **self._negative_provenance(beta),
                         **(provenance or {})})
        if not self.is_spectral:
            meta["colour_space"] = "linear sRGB"
        return make_dataset(table, meta, source=self.path)


def incidence_meta(file_incidence_deg, dataset_incidence_deg, source: str) -> dict:
    """``incidences`` of a dataset made from a file (an RGL ``.bsdf``).

    The file's measured incidences, and which of the dataset's are the file's interpolation between
    them (not within 0.01 deg of a measured one).
    """
    measured = sorted({round(float(t), 4) for t in file_incidence_deg})
    used = sorted({round(float(t), 4) for t in dataset_incidence_deg})
    interpolated = [t for t in used if min(abs(t - m) for m in measured) > 0.01]
    return {"source": source, "measured_deg": measured, "interpolated_deg": interpolated,
            "note": ("every incidence is one the file measured" if not interpolated else
                     f"incidences {', '.join(f'{t:g}' for t in interpolated)} deg are interpolated between the "
                     "file's measured tables, not measured")}


def _labels(bsdf: RGLBSDF) -> list[str]:
    return (list(bsdf.channels) if not bsdf.is_spectral
            else [f"{w:g} nm" for w in np.asarray(bsdf.wavelengths_nm)])


def read_rgl_bsdf(path: str | os.PathLike) -> RGLBSDF:
    """Read and check an RGL ``.bsdf`` file; raise :class:`FormatError` naming what is wrong.

    The declared shapes are checked before any table is read (:func:`_check_header`): a file
    declaring more incidence angles than :data:`MAX_ANGLES` per axis is refused from its header.
    Negative stored values (measurement noise below zero) are kept and counted per band
    (:attr:`RGLBSDF.negative_values`; ``gonio import`` says so in its summary).
    """
    return RGLBSDF(read_tensor_file(path, lambda headers: _check_header(headers, str(path))), path)


def _check_header(headers: dict[str, TensorHeader], path: str) -> None:
    """Plausibility of the declared incidence axes, before the tables are read."""
    for name in ("theta_i", "phi_i"):
        h = headers.get(name)
        if h is not None and len(h.shape) == 1 and h.shape[0] > MAX_ANGLES:
            raise FormatError(f"field '{name}' declares {h.shape[0]} incidence angles, more than "
                              f"{MAX_ANGLES}", file=path, offset=h.start,
                              hint="not an RGL .bsdf file (they hold about ten), or corrupt")


def _check_structure(fields: dict[str, np.ndarray], path: str) -> None:  # noqa: C901
    """The shape and type checks of Mitsuba's ``measured`` plugin, with a message for each."""
    def fail(problem: str) -> None:
        raise FormatError(problem, file=path, hint="not a valid RGL .bsdf file (Dupuy & Jakob "
                                                   "2018 tensor layout)")

    missing = [f for f in _REQUIRED if f not in fields]
    spectral = "wavelengths" in fields
    values_name = "spectra" if spectral else "rgb"
    if values_name not in fields:
        missing.append(values_name)
    if missing:
        fail(f"missing field(s) {', '.join(missing)}")
    f32 = np.dtype(np.float32)

    def expect(name: str, ndim: int, dtype=f32) -> np.ndarray:
        a = fields[name]
        if a.ndim != ndim or a.dtype != dtype:
            fail(f"field '{name}' must be {ndim}-D {dtype.name}, not {a.ndim}-D {a.dtype.name}")
        if dtype == f32 and not np.all(np.isfinite(a)):
            fail(f"field '{name}' contains NaN or infinite values")
        return a

    theta_i = expect("theta_i", 1)
    phi_i = expect("phi_i", 1)
    expect("description", 1, np.dtype(np.uint8))
    jac = expect("jacobian", 1, np.dtype(np.uint8))
    if jac.shape != (1,):
        fail("field 'jacobian' must hold one byte")
    ndf, sigma = expect("ndf", 2), expect("sigma", 2)
    vndf, lum = expect("vndf", 4), expect("luminance", 4)
    values = expect(values_name, 5)
    n_bands = 3
    if spectral:
        wl = expect("wavelengths", 1)
        n_bands = wl.size
        if wl.size < 1 or not np.all(np.diff(wl) > 0):
            fail("field 'wavelengths' must be increasing")
    for name, a in (("vndf", vndf), ("luminance", lum), (values_name, values)):
        if a.shape[0] != phi_i.size or a.shape[1] != theta_i.size:
            fail(f"field '{name}' has shape {list(a.shape)}; its first two axes must match "
                 f"phi_i ({phi_i.size}) and theta_i ({theta_i.size})")
    if values.shape[2] != n_bands:
        fail(f"field '{values_name}' has {values.shape[2]} bands, expected {n_bands}")
    if lum.shape[2:] != values.shape[3:]:
        fail(f"fields 'luminance' {list(lum.shape)} and '{values_name}' {list(values.shape)} "
             "disagree on the table size")
    for name, a in (("ndf", ndf), ("sigma", sigma), ("vndf", vndf), (values_name, values)):
        if min(a.shape[-2:]) < 2:
            fail(f"field '{name}' needs tables of at least 2 x 2, not {list(a.shape[-2:])}")
    if theta_i.size < 1 or phi_i.size < 1 or not np.all(np.diff(theta_i) > 0):
        fail("field 'theta_i' must be non-empty and increasing")
    if np.any(theta_i < 0) or np.any(theta_i > np.pi / 2 + 1e-6):
        fail("field 'theta_i' must be in [0, pi/2] radians")
    if phi_i.size > 2 and not np.all(np.diff(phi_i) > 0):
        fail("field 'phi_i' must be increasing")
    if phi_i.size > 2:
        # an anisotropic table spans one period of the material's symmetry: 2 pi, pi or pi/2
        span = float(phi_i[-1]) - float(phi_i[0])
        reduction = 2 * np.pi / span if span > 0 else np.inf
        if not any(abs(reduction - r) < 1e-3 * r for r in (1, 2, 4)):
            fail(f"field 'phi_i' spans {span:.6g} rad; an anisotropic table spans 2 pi, pi or "
                 "pi/2 (symmetry reduction 1, 2 or 4)")
        if np.min(np.diff(phi_i)) < 1e-6:
            fail("field 'phi_i' holds angles less than 1e-6 rad apart")
    if np.any(vndf < 0) or np.any(ndf < 0) or np.any(sigma <= 0):
        fail("fields 'vndf' and 'ndf' must be >= 0 and 'sigma' > 0")
    sums = vndf.reshape(vndf.shape[0], vndf.shape[1], -1).sum(axis=-1)
    if np.any(sums <= 0):
        fail("field 'vndf' has an all-zero table (no visible normals)")
