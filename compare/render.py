"""Fabrics rendered with Mitsuba 3 from exported RGL ``.bsdf`` files, and the export checks.

Mitsuba 3 is an optional dependency (the ``render`` extra, ``pip install -e '.[render]'``); every
function imports it through :func:`require_mitsuba`, which turns its absence into one line
saying how to install it. Only the CPU *scalar* variants are used (``scalar_rgb`` for RGB files,
``scalar_spectral`` for spectral ones: Mitsuba's ``measured`` plugin accepts each file type only
in the matching variant).

Checks of an exported file against Mitsuba (:func:`mitsuba_eval`, :func:`sampling_chi2`):

- ``eval`` at direction pairs, as ``f_r cos(theta_o)`` per band;
- its ``sample`` as an importance sampler: Pearson's chi-square test of N sampled directions,
  binned on a (``cos theta_o``, ``phi_o``) grid, against the expected counts from a density
  integrated over each cell (midpoint rule on a sub-grid): either Mitsuba's own ``pdf`` (is the
  sampler what it says it is?) or the density derived from ``eval`` (``Y(f_r cos)`` normalised:
  does it sample where the BRDF is?). Cells with fewer than 5 expected samples are pooled, as in
  Mitsuba's ``mitsuba.chi2`` (whose vectorised test needs an LLVM/CUDA variant, unavailable here).

References
----------
Mitsuba 3 documentation (``measured`` BSDF; ``mitsuba.chi2.ChiSquareTest``, the binning and
pooling learned from it). W. Jakob et al., Mitsuba 3 (2022).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

__all__ = ["MitsubaMissing", "mitsuba_eval", "require_mitsuba", "sampling_chi2"]

INSTALL_HINT = "Mitsuba 3 is not installed: install the render extra, pip install -e '.[render]' (mitsuba==3.9.1)"


class MitsubaMissing(RuntimeError):
    """Mitsuba 3 is not importable; the message says how to install it."""


def require_mitsuba(variant: str = "scalar_rgb") -> Any:
    """The ``mitsuba`` module with ``variant`` set; :class:`MitsubaMissing` (one line) without it."""
    try:
        import mitsuba as mi
    except ImportError:
        raise MitsubaMissing(INSTALL_HINT) from None
    mi.set_variant(variant)
    return mi


def _file_is_spectral(path: str | os.PathLike) -> bool:
    from gonio.data.formats.tensor import read_tensor_file

    return "wavelengths" in read_tensor_file(path)


def load_measured(path: str | os.PathLike) -> tuple[Any, Any, np.ndarray | None]:
    """``(mitsuba, bsdf, wavelengths or None)`` for an RGL file, in the variant its type needs."""
    from gonio.data.formats.tensor import read_tensor_file

    fields = read_tensor_file(path)
    spectral = "wavelengths" in fields
    mi = require_mitsuba("scalar_spectral" if spectral else "scalar_rgb")
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
    return mi, bsdf, (np.asarray(fields["wavelengths"], float) if spectral else None)


def mitsuba_eval(path: str | os.PathLike, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Mitsuba's ``eval`` (``f_r cos theta_o``) of the file at pairs ``(N, 3)``: ``(N, bands)``.

    Spectral files are evaluated at their own wavelengths (four per call, Mitsuba's bundle).
    """
    mi, bsdf, wl = load_measured(path)
    ctx = mi.BSDFContext()
    n_bands = 3 if wl is None else wl.size
    out = np.empty((len(wi), n_bands))
    si = mi.SurfaceInteraction3f()
    for k, (a, b) in enumerate(zip(np.asarray(wi, float), np.asarray(wo, float))):
        si.wi = mi.Vector3f(*a)
        if wl is None:
            out[k] = list(bsdf.eval(ctx, si, mi.Vector3f(*b)))
            continue
        for start in range(0, n_bands, 4):
            chunk = wl[start:start + 4]
            si.wavelengths = mi.Spectrum(list(np.pad(chunk, (0, 4 - chunk.size), mode="edge")))
            out[k, start:start + chunk.size] = list(bsdf.eval(ctx, si, mi.Vector3f(*b)))[:chunk.size]
    return out


def _bins(wo: np.ndarray, n_cos: int, n_phi: int) -> np.ndarray:
    ic = np.clip((wo[:, 2] * n_cos).astype(int), 0, n_cos - 1)
    phi = np.mod(np.arctan2(wo[:, 1], wo[:, 0]), 2 * np.pi)
    ip = np.clip((phi / (2 * np.pi) * n_phi).astype(int), 0, n_phi - 1)
    return ic * n_phi + ip


def sampling_chi2(path: str | os.PathLike, theta_i_deg: float, *, n_samples: int = 100_000,
                  n_cos: int = 20, n_phi: int = 40, sub: int = 4, seed: int = 0,
                  against: str = "pdf") -> dict[str, float]:
    """Chi-square test of Mitsuba's ``sample`` at incidence ``theta_i_deg`` (``phi_i = 0``).

    ``against``: ``"pdf"`` (Mitsuba's ``pdf``) or ``"eval"`` (the luminance of ``eval``,
    normalised by its integral over the hemisphere). Returns the statistic, degrees of freedom,
    p-value, the largest relative mismatch of the sample weight ``eval / pdf`` and the sampled
    fraction that came back invalid (zero weight).
    """
    from scipy.stats import chi2 as chi2_dist

    mi, bsdf, wl = load_measured(path)
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    t = np.radians(theta_i_deg)
    si.wi = mi.Vector3f(np.sin(t), 0.0, np.cos(t))
    if wl is not None:
        si.wavelengths = mi.Spectrum([550.0] * 4)
    rng = np.random.default_rng(seed)
    u = rng.random((n_samples, 3))
    wo = np.empty((n_samples, 3))
    ok = np.zeros(n_samples, bool)
    weight_err = 0.0
    for k in range(n_samples):
        bs, weight = bsdf.sample(ctx, si, float(u[k, 0]), mi.Point2f(float(u[k, 1]), float(u[k, 2])))
        w = np.asarray(list(weight), float)
        ok[k] = bool(np.any(w > 0)) and bs.pdf > 0
        wo[k] = list(bs.wo)
        if ok[k] and k < 2000:      # the weight must be eval / pdf
            ev = np.asarray(list(bsdf.eval(ctx, si, bs.wo)), float)
            weight_err = max(weight_err, float(np.max(np.abs(w * bs.pdf - ev) / np.maximum(ev, 1e-12))))
    observed = np.bincount(_bins(wo[ok], n_cos, n_phi), minlength=n_cos * n_phi).astype(float)
    # density at a sub-grid of each (cos theta, phi) cell; d omega = d(cos) d(phi)
    c = (np.arange(n_cos * sub) + 0.5) / (n_cos * sub)
    p = (np.arange(n_phi * sub) + 0.5) / (n_phi * sub) * 2 * np.pi
    cc, pp = np.meshgrid(c, p, indexing="ij")
    s = np.sqrt(1 - cc ** 2)
    dirs = np.stack([s * np.cos(pp), s * np.sin(pp), cc], axis=-1).reshape(-1, 3)
    dens = np.empty(len(dirs))
    ylum = np.array([0.212671, 0.715160, 0.072169]) if wl is None else None
    for k, d in enumerate(dirs):
        v = mi.Vector3f(*d)
        if against == "pdf":
            dens[k] = bsdf.pdf(ctx, si, v)
        else:
            ev = np.asarray(list(bsdf.eval(ctx, si, v)), float)
            dens[k] = float(ev @ ylum) if ylum is not None else float(ev.mean())
    cell = (1.0 / (n_cos * sub)) * (2 * np.pi / (n_phi * sub))
    dens = dens.reshape(n_cos, sub, n_phi, sub).sum(axis=(1, 3)) * cell
    if against == "eval":      # the valid samples against the normalised eval density
        dens = dens / dens.sum() * ok.mean()
    expected = dens.ravel() * n_samples
    order = np.argsort(expected)
    e_sorted, o_sorted = expected[order], observed[order]
    # pool the smallest expected cells until each pooled cell expects >= 5 samples
    pooled_e, pooled_o, acc_e, acc_o = [], [], 0.0, 0.0
    for e, o in zip(e_sorted, o_sorted):
        acc_e += e
        acc_o += o
        if acc_e >= 5:
            pooled_e.append(acc_e)
            pooled_o.append(acc_o)
            acc_e = acc_o = 0.0
    if acc_e > 0 and pooled_e:
        pooled_e[-1] += acc_e
        pooled_o[-1] += acc_o
    pe, po = np.array(pooled_e), np.array(pooled_o)
    stat = float(np.sum((po - pe) ** 2 / pe))
    dof = pe.size - 1
    return {"chi2": stat, "dof": float(dof), "p_value": float(chi2_dist.sf(stat, dof)),
            "weight_rel_err_max": weight_err, "invalid_fraction": float(1 - ok.mean()),
            "expected_total": float(expected.sum())}
