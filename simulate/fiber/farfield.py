r"""The whole fiber's far-field scattering function and its exit table (docs/physics.md section 5.1).

A fiber is an infinite cylinder (:mod:`simulate.fiber`): fiber frame x = axis ``t``, a surface
cell at azimuth ``psi`` has the outward normal ``n(psi) = (0, -sin psi, cos psi)`` and the local
frame ``(t, b(psi), n(psi))``, ``b(psi) = n x t = (0, cos psi, sin psi)``. Under a parallel beam of
irradiance ``E_perp`` from ``w_i`` the radiant intensity per unit fiber length leaving the WHOLE
fiber towards ``w_o``, per unit ``E_perp``, is the far-field scattering function (the quantity hair
and fiber models are built on: Marschner et al. 2003, d'Eon et al. 2011; their ``S`` per unit
length and unit irradiance)::

    S(w_i, w_o) = int_0^{2 pi} R_psi(w_i, w_o) (w_o . n(psi))_+ R dpsi              [um / sr]

``R_psi = L_o / E_perp`` is the radiance coefficient of the cell at ``psi`` (the fiber BRDF of
docs/physics.md section 5, surface plus volume). The cylinder is invariant under turns about its
axis, so ``R_psi(w_i, w_o) = R_B(X(-psi) w_i, X(-psi) w_o)``: the top cell's, with both directions
rotated by ``-psi`` about x, i.e. expressed in the cell's own frame ``(w.t, w.b(psi), w.n(psi))``.
With cells of width ``dpsi`` centred on ``psi_k = k dpsi`` the integral is the cell sum::

    S ~ sum_k R dpsi (w_o . n_k)_+ R_vol,k(w_i, w_o)  +  S_surf

(each cell's radiance is its cell average, so the error is second order in ``dpsi``: the
projected width is taken at the centre). Its total is the fiber's albedo: the power leaving per
unit length over the power intercepted, ``2 R |w_perp|`` per unit length::

    int_{4 pi} S dOmega_o = a(w_i) 2 R |w_perp|

The surface term is integrated analytically (Cook-Torrance at every point, a fine midpoint rule
in ``psi``): ``S_surf = int R (w_o.n)_+ (w_i.n)_+ f_CT(local w_i, local w_o) dpsi``.

Two ways to get the volume term:

:func:`far_field_nee`
    The next-event route of :func:`simulate.fiber.volume_brdf` at point directions, ONE call on
    all pairs: for each pair and each cell facing ``w_o`` an output row at that cell (the
    kernel's outputs take any cell centre ``psi_c``), so the beam from ``w_i`` is walked once and
    scores every cell -- exactly the rotated pairs ``(X(-psi_k) w_i, X(-psi_k) w_o)`` of the
    relation above, without one walk per rotation. Light that never scattered (a delta on the
    refraction cone) is not in point outputs (as for ``R_B``).
:class:`ExitTable`
    The fiber's exit table: the BSSRDF rows of :func:`simulate.fiber.bssrdf_table` (the original
    method's table: photons entering ONE cell A under a beam, exits binned by cell offset and
    local direction) at a few axial components ``|w_t|``. Because the rows are per ENTRY cell,
    any subset of entry cells may be lit (shadowing by neighbours) and any subset of exit cells
    seen (masking): the visible-surface average of :mod:`simulate.fabric.fiberlayer` is built on it. Rows
    ``k`` and ``-k`` are averaged through the cylinder's mirror symmetry (half the variance).
    A beam at azimuth ``beta`` about the axis (``w_perp`` along ``n(beta)``) lights cell ``A_i``
    at the local azimuth ``beta - psi_i``, row ``k = (beta - psi_i) / dpsi``; azimuths between
    multiples of ``dpsi`` and ``|w_t|`` between the table's nodes are interpolated linearly
    (as :mod:`simulate.fiber`'s ``bssrdf`` route does in ``beta``); in ``|w_t|`` the exit
    distribution per unit ENTERING light is interpolated and the exact entry of the actual ``|w_t|``
    restored (a row's launch weight ``w . n`` and its transmission ``1 - F`` belong to its node; the
    woven Monte Carlo divides out the row's entry in the same way). Exit directions are binned
    (``n_mu x n_phi`` in the cell's local ``cos theta`` and azimuth), so the table's far field
    is the bin average of the radiance: piecewise constant in the local exit direction.

References
----------
Marschner, S. R., Jensen, H. W., Cammarano, M., Worley, S. & Hanrahan, P. (2003). Light
scattering from human hair fibers. *ACM TOG* 22(3), 780-791. d'Eon, E., Francois, G., Hill, M.,
Letteri, J. & Aubry, J.-M. (2011). An energy-conserving hair reflectance model. *Computer Graphics
Forum* 30(4), 1181-1187. docs/physics.md sections 4, 5 and 5.1.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass
from dataclasses import replace as dataclasses_replace
from typing import Any

import numba
import numpy as np

from simulate.fiber import tablecache
from simulate.optics import microfacet
from simulate.optics.fresnel import OpticsDomainWarning, reflectance_from_cos

log = logging.getLogger(__name__)

__all__ = ["CachedMedium", "ExitTable", "cached", "cell_frame", "exit_table", "far_field_nee", "surface_far_field", "DEFAULT_WT_NODES",
           "merged", "controlled_halves", "MIN_PHOTONS_PER_ROW", "MAX_ROUNDS", "ROUND_SEED_STRIDE"]

#: axial components ``|w_t|`` of the exit table's rows (linear interpolation between them).
DEFAULT_WT_NODES = (0.0, 0.26, 0.5, 0.71, 0.87, 0.97)


def cell_frame(w: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Fiber-frame directions ``w [..., 3]`` in the local frame ``(t, b(psi), n(psi))`` of the cell at ``psi``.

    This is the rotation ``X(-psi)`` about the axis: the top cell's frame is the fiber frame.

    Parameters
    ----------
    w : numpy.ndarray
        ``[..., 3]`` directions in the fiber frame.
    psi : numpy.ndarray
        The cells' azimuths (radians), broadcast against ``w[..., 0]``.

    Returns
    -------
    numpy.ndarray
        ``[..., 3]`` the same directions in each cell's frame.
    """
    w = np.asarray(w, float)
    psi = np.asarray(psi, float)
    c, s = np.cos(psi), np.sin(psi)
    return np.stack([np.broadcast_to(w[..., 0], np.broadcast(w[..., 0], c).shape),
                     w[..., 1] * c + w[..., 2] * s, -w[..., 1] * s + w[..., 2] * c], axis=-1)


def surface_far_field(fiber: Any, w_in: np.ndarray, w_out: np.ndarray, n_psi: int = 720,
                      visibility: Any = None) -> np.ndarray:
    """``S_surf [P]`` (um/sr): the Cook-Torrance term integrated over the cylinder's azimuth.

    Parameters
    ----------
    fiber : Fiber
        The fiber (radius, roughness, index).
    w_in, w_out : numpy.ndarray
        ``[P, 3]`` paired incident and exit directions in the fiber frame.
    n_psi : int
        Azimuth nodes of the integral.
    visibility : callable, optional
        ``visibility(w, psi) -> [P, n_psi]`` in [0, 1]: the fraction of the point at ``psi`` seen from
        ``w`` (masking and shadowing); it multiplies both the lit and the seen factor.

    Returns
    -------
    numpy.ndarray
        ``[P]`` the surface term (um/sr).
    """
    w_in = np.atleast_2d(np.asarray(w_in, float))
    w_out = np.atleast_2d(np.asarray(w_out, float))
    dpsi = 2.0 * math.pi / n_psi
    psi = (np.arange(n_psi) + 0.5) * dpsi - math.pi
    li = cell_frame(w_in[:, None, :], psi[None, :])
    lo = cell_frame(w_out[:, None, :], psi[None, :])
    ok = (li[..., 2] > 0) & (lo[..., 2] > 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OpticsDomainWarning)  # grazing points: finite, vanishing weight
        f = microfacet.cook_torrance(np.where(ok[..., None], li, [0.0, 0.0, 1.0]),
                                     np.where(ok[..., None], lo, [0.0, 0.0, 1.0]), fiber.roughness, fiber.n_host)
    weight = np.where(ok, f * li[..., 2] * lo[..., 2], 0.0)
    if visibility is not None:
        weight = weight * visibility(w_in, psi) * visibility(w_out, psi)
    return fiber.radius_um * dpsi * weight.sum(axis=1)


def far_field_nee(fiber: Any, w_in: np.ndarray, w_out: np.ndarray, wavelengths_nm: Any, *,
                  surface: bool = True, **mc: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """``S(w_i, w_o)`` by next-event estimation: ``S_vol [P, L]``, ``u_S_vol [P, L]``, ``S_surf [P]``, info.

    One :func:`simulate.fiber.volume_brdf` call (``method="nee"``) with an output row per pair
    and per cell of the fiber's cell width facing ``w_o`` (module docstring). ``u`` adds the cells'
    errors linearly (they share photons: the correlated bound).

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    w_in, w_out : numpy.ndarray
        ``[P, 3]`` paired incident and exit directions in the fiber frame.
    wavelengths_nm : array_like
        Vacuum wavelengths (nm).
    surface : bool
        Also integrate the surface term (else ``S_surf`` is zero).
    **mc
        Passed to :func:`simulate.fiber.volume_brdf` (``target_rel_err``, ``seed``, ``threads``, ...).

    Returns
    -------
    S_vol, u_S_vol : numpy.ndarray
        ``[P, L]`` volume term and its error.
    S_surf : numpy.ndarray
        ``[P]`` surface term.
    info : dict
        ``photons``, ``seconds``, ``outputs`` and the fiber run's information.
    """
    from simulate import fiber as fiber_mod

    w_in = np.atleast_2d(np.asarray(w_in, float))
    w_out = np.atleast_2d(np.asarray(w_out, float))
    n_cells = int(round(360.0 / fiber.cell_width_deg))
    dpsi = 2.0 * math.pi / n_cells
    psi = np.arange(n_cells) * dpsi
    local = cell_frame(w_out[:, None, :], psi[None, :])            # [P, K, 3]
    pair, cell = np.nonzero(local[..., 2] > 1e-9)
    lo = local[pair, cell]
    phi = np.arctan2(lo[:, 1], lo[:, 0])
    outputs = fiber_mod.range_outputs(lo[:, 2], lo[:, 2], phi, phi, dpsi / 2.0, psi[cell])  # type: ignore[arg-type]  # psi_c broadcasts
    mc = {"method": "nee", **mc}
    est = fiber_mod.volume_brdf(fiber, w_in[pair], None, wavelengths_nm, outputs=outputs, **mc)
    width = fiber.radius_um * dpsi * lo[:, 2]
    S = np.zeros((w_in.shape[0], est.R.shape[1]))
    u = np.zeros_like(S)
    np.add.at(S, pair, width[:, None] * est.R)
    np.add.at(u, pair, width[:, None] * est.u_R)
    s_surf = surface_far_field(fiber, w_in, w_out) if surface else np.zeros(w_in.shape[0])
    return S, u, s_surf, {"photons": int(est.photons), "seconds": est.seconds, "outputs": int(pair.size),
                          "fiber_info": est.info}


@numba.njit(cache=True, parallel=True, nogil=True)
def _accumulate_beam(T, k_min, nodes, js, weights, scales, lit, out):
    """Add one beam's exit-table terms to its far field ``out``.

    ``out[B] += weights[c] scales[c, k] lit[i] T[nodes[c], k, B - i]`` over the terms ``c`` (node ``nodes[c]``,
    beam azimuth cell ``js[c]``) and the lit entry cells ``i``, row ``k = js[c] - i`` (wrapped).

    Parallel over the exit cells ``B``, each ``out[B]`` (one exit cell's bins and channels, ~10^5 values)
    summed while it stays in cache, rather than streaming the whole ``out`` through memory once per lit cell
    and term. The additions per value run in the order term, then entry cell, the order of the plain loop
    over terms and entry cells: the numbers do not depend on the loop's arrangement.
    """
    n = out.shape[0]
    inner = out[0].size
    flat_out = out.reshape(n, inner)
    flat_T = T.reshape(T.shape[0], T.shape[1], n, inner)
    for b in numba.prange(n):
        for c in range(nodes.size):
            for i in range(n):
                k = ((js[c] - i) + n // 2) % n - n // 2      # row azimuth in (-180, 180] deg
                if k < k_min or k > -k_min or lit[i] == 0.0:
                    continue
                w = scales[c, k - k_min] * weights[c] * lit[i]
                src = (b - i) % n
                for q in range(inner):
                    flat_out[b, q] += w * flat_T[nodes[c], k - k_min, src, q]


@dataclass
class ExitTable:
    """The fiber's BSSRDF rows at axial components ``w_t`` (module docstring), v summed out.

    Attributes
    ----------
    w_t : numpy.ndarray
        ``[W]`` nodes of ``|w_t|`` (increasing, from 0).
    T, u_T : numpy.ndarray
        ``[W, K, n_psi, n_mu, n_phi, L]``: mean exit weight per photon entering cell A with the
        local incidence of row ``k`` (launch weight ``max(w . n, 0)``), by exit cell offset and
        local exit bin; and its standard error.
    k : numpy.ndarray
        ``[K]`` row azimuths in cell widths (``-k_max .. k_max``).
    radius_um, wavelengths_nm, photons, seconds
    """

    w_t: np.ndarray
    T: np.ndarray
    u_T: np.ndarray
    k: np.ndarray
    radius_um: float
    wavelengths_nm: np.ndarray
    photons: int = 0
    seconds: float = 0.0
    n_host: float = 1.5

    def entry(self, w_t: float) -> np.ndarray:
        """``[K]`` each row's cell-averaged launch weight times entry transmission, ``<(w.n)(1 - F)>``, at ``|w_t|``."""
        rho = math.sqrt(max(1.0 - w_t * w_t, 0.0))
        sub = ((np.arange(64) + 0.5) / 64 - 0.5) * self.dpsi
        cos = np.clip(rho * np.cos(self.k[:, None] * self.dpsi + sub[None, :]), 0.0, 1.0)
        return np.mean(cos * (1.0 - reflectance_from_cos(cos, 1.0, self.n_host)), axis=1)

    @property
    def n_psi(self) -> int:
        """Number of azimuth cells around the fiber's section."""
        return int(self.T.shape[2])

    @property
    def dpsi(self) -> float:
        """Width of one azimuth cell (radians)."""
        return 2.0 * math.pi / self.n_psi

    @property
    def bins(self) -> tuple[int, int]:
        """Local exit bins ``(n_mu, n_phi)``: cosine bins from the surface normal and azimuth bins."""
        return int(self.T.shape[3]), int(self.T.shape[4])

    def omega(self) -> np.ndarray:
        """Projected solid angle ``[n_mu]`` of a local exit bin (the same for every azimuth bin)."""
        n_mu, n_phi = self.bins
        e = np.linspace(0.0, 1.0, n_mu + 1)
        return 0.5 * (e[1:] ** 2 - e[:-1] ** 2) * (2.0 * math.pi / n_phi)

    def exit_radiance(self, w_in: np.ndarray, lit: np.ndarray | None = None) -> np.ndarray:
        """Radiance coefficients ``[n_psi, n_mu, n_phi, L]`` of every exit cell and local bin for ONE beam.

        ``lit [n_psi]`` (optional, in [0, 1]): the fraction of each entry cell's irradiance that
        reaches it (shadowing); default 1. ``w_in`` in the fiber frame; a negative ``w_t`` uses
        the mirror ``x -> -x`` (exit azimuth ``phi -> pi - phi``).
        """
        w_in = np.asarray(w_in, float)
        wt = abs(float(w_in[0]))
        beta = math.atan2(-float(w_in[1]), float(w_in[2]))
        n = self.n_psi
        lit = np.ones(n) if lit is None else np.asarray(lit, float)
        x = beta / self.dpsi
        j0 = math.floor(x)
        frac = x - j0
        iw = int(np.clip(np.searchsorted(self.w_t, wt) - 1, 0, self.w_t.size - 2))
        fw = float(np.clip((wt - self.w_t[iw]) / (self.w_t[iw + 1] - self.w_t[iw]), 0.0, 1.0))
        k_min = int(self.k[0])
        out = np.zeros(self.T.shape[2:])
        tau = self.entry(wt)
        nodes, js, weights, scales = [], [], [], []
        for wi, aw in ((iw, 1.0 - fw), (iw + 1, fw)):
            if aw == 0.0:
                continue
            # a row carries the node's launch weight and entry transmission: interpolate the exit
            # distribution per unit entering light and restore the exact entry of this w_t
            scale = aw * tau / self.entry(float(self.w_t[wi]))
            for j, ab in ((j0, 1.0 - frac), (j0 + 1, frac)):
                if ab == 0.0:
                    continue
                nodes.append(wi)
                js.append(j)
                weights.append(ab)
                scales.append(scale)
        # one pass over the exit cells for the (up to four) node x azimuth terms
        _accumulate_beam(np.ascontiguousarray(self.T), k_min, np.array(nodes, np.int64), np.array(js, np.int64),
                         np.array(weights, float), np.array(scales, float).reshape(len(scales), -1), lit, out)
        out /= self.omega()[None, :, None, None]
        if w_in[0] < 0:
            n_phi = self.bins[1]
            centres = (np.arange(n_phi) + 0.5) * 2.0 * math.pi / n_phi - math.pi
            mirror = np.floor(((math.pi - centres + math.pi) % (2.0 * math.pi)) / (2.0 * math.pi / n_phi)).astype(int)
            out = out[:, :, mirror]
        return out

    def lookup(self, radiance: np.ndarray, w_out: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Gather ``radiance [n_psi, n_mu, n_phi, L]`` at ``w_out [O, 3]``: ``R [O, n_psi, L]`` and ``cos [O, n_psi]``.

        ``cos = w_out . n_B`` at each cell centre (0 where the cell faces away).
        """
        w_out = np.atleast_2d(np.asarray(w_out, float))
        n_mu, n_phi = self.bins
        psi = np.arange(self.n_psi) * self.dpsi
        local = cell_frame(w_out[:, None, :], psi[None, :])
        mu = local[..., 2]
        phi = np.arctan2(local[..., 1], local[..., 0])
        i_mu = np.clip((mu * n_mu).astype(int), 0, n_mu - 1)
        i_phi = np.clip(((phi + math.pi) / (2.0 * math.pi) * n_phi).astype(int), 0, n_phi - 1)
        cells = np.broadcast_to(np.arange(self.n_psi), mu.shape)
        R = radiance[cells, i_mu, i_phi]
        return R, np.clip(mu, 0.0, None)

    def far_field(self, w_in: np.ndarray, w_out: np.ndarray) -> np.ndarray:
        """Volume far field ``S_vol [O, L]`` (um/sr) for ONE beam ``w_in`` and exit directions ``w_out [O, 3]``."""
        R, cos = self.lookup(self.exit_radiance(w_in), w_out)
        return self.radius_um * self.dpsi * np.einsum("ok,okl->ol", cos, R)

    def albedo(self, w_in: np.ndarray) -> np.ndarray:
        """The fiber's volume albedo ``[L]`` from the cell sum: all exits of all lit entry cells / ``2 R |w_perp|``."""
        rad = self.exit_radiance(w_in) * self.omega()[None, :, None, None]
        w_in = np.asarray(w_in, float)
        return self.radius_um * self.dpsi * rad.sum(axis=(0, 1, 2)) / (2.0 * self.radius_um * math.hypot(w_in[1], w_in[2]))


def _symmetrised(T: np.ndarray) -> np.ndarray:
    """Average each row with the mirror image of its opposite: ``T[-k](o, mu, phi) = T[k](-o, mu, -phi)``.

    The mirror ``b -> -b`` of the cell frame (the cylinder is symmetric about the plane through its
    axis and the cell's normal) maps the local incidence azimuth ``a`` to ``-a``, the exit cell offset
    to its opposite and the local exit azimuth to its opposite: exact, and it halves the variance.
    """
    n_k, n_psi, n_mu, n_phi = T.shape[1:5]
    offsets = (-np.arange(n_psi)) % n_psi
    phis = n_phi - 1 - np.arange(n_phi)
    # one gather per node into one C-ordered array, sums in place: red cotton's table is ~175 MB per
    # half, and every temporary costs page faults
    index = (np.arange(n_k)[::-1, None, None, None], offsets[None, :, None, None],
             np.arange(n_mu)[None, None, :, None], phis[None, None, None, :])
    out = np.empty_like(T)
    for i in range(T.shape[0]):
        out[i] = T[i][index]
        out[i] += T[i]
    out *= 0.5
    return out


class CachedMedium:
    """A medium whose optical properties are computed once per wavelength (Mie: ~0.15 s each).

    :func:`simulate.fiber.bssrdf_table` evaluates the medium at every call; the exit table calls it
    once per ``w_t`` node, so without the cache the Mie computations cost more than the photons.
    """

    def __init__(self, medium: Any):
        self.medium = medium
        self._cache: dict[float, Any] = {}

    def optical_properties(self, wavelength_nm: float) -> Any:
        """The wrapped medium's optical properties at ``wavelength_nm``, computed once per wavelength."""
        key = float(wavelength_nm)
        if key not in self._cache:
            self._cache[key] = self.medium.optical_properties(key)
        return self._cache[key]


def cached(fiber: Any) -> Any:
    """``fiber`` with a :class:`CachedMedium` (the same fiber if it already has one).

    Parameters
    ----------
    fiber : Fiber
        Any fiber.

    Returns
    -------
    Fiber
        A copy whose medium computes each wavelength's optics once.
    """
    import dataclasses

    if isinstance(fiber.medium, CachedMedium):
        return fiber
    return dataclasses.replace(fiber, medium=CachedMedium(fiber.medium))


def exit_table(fiber: Any, wavelengths_nm: Any, *, w_t: Any = DEFAULT_WT_NODES, bins: tuple[int, int] = (9, 18),
               photons_per_row: int = 20_000, seed: int = 0, threads: int | None = None,
               max_group: int = 7, cache: bool = True) -> ExitTable:
    """The :class:`ExitTable` of ``fiber`` from :func:`simulate.fiber.bssrdf_table` at each ``w_t`` node.

    Streams: node ``i`` uses the seed ``seed * 1000003 + 104729 i``, its wavelength group ``k`` adds
    ``1009 k`` and its rows ``7919 r`` (:func:`simulate.fiber.bssrdf_table`, ``r < 19``): for up to 8
    nodes and 33 groups these offsets are distinct for distinct ``(i, k, r)`` and stay below 1000003,
    so different seeds, nodes and groups never share a stream (two independent tables need only two
    seeds).

    No white-Monte-Carlo group spans more than ``max_group`` consecutive wavelengths (red cotton:
    5 walks instead of 3): the spectral re-weighting's variance grows with the distance from the
    group's reference wavelength; a 21-wavelength group (510-710 nm) gave rare heavy weights at
    710 nm that the closure of :mod:`simulate.fabric.interior` amplifies. Neighbouring groups are
    blended across their boundary (:func:`simulate.fiber.spectral.blended_groups`).

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    wavelengths_nm : array_like
        Vacuum wavelengths (nm).
    w_t : array_like
        The axial incidence nodes.
    bins : tuple of int
        Local exit bins ``(n_mu, n_phi)``.
    photons_per_row : int
        Photons per row, node and wavelength group.
    seed : int
        Random seed.
    threads : int, optional
        Threads (results do not depend on it).
    max_group : int
        Largest wavelength group of one walk.
    cache : bool
        Read and store the table in the disk cache (:mod:`simulate.fiber.tablecache`, key
        :func:`exit_table_key`): a second ``simulate fabric --method summation`` of the same fiber at
        the same photons reads its tables (each round of :func:`controlled_halves` is one entry); a hit
        is bit-identical to the walk that stored it.

    Returns
    -------
    ExitTable
        Rows at every node, their errors, photons and seconds.
    """
    nodes = np.asarray(w_t, float)
    if nodes.ndim != 1 or nodes.size < 2 or nodes[0] != 0.0 or np.any(np.diff(nodes) <= 0) or nodes[-1] >= 1.0:
        raise ValueError("exit_table: w_t must be increasing nodes from 0 to below 1 (at least two)")
    t0 = time.perf_counter()
    wl = np.atleast_1d(np.asarray(wavelengths_nm, float))
    key = exit_table_key(fiber, wl, nodes, bins, photons_per_row, seed, max_group) if cache else None
    if key is not None:
        got = tablecache.load(key)
        if got is not None and all(k in got for k in ("T", "u_T", "k", "photons")):
            return ExitTable(w_t=nodes, T=got["T"], u_T=got["u_T"], k=got["k"], radius_um=fiber.radius_um,
                             wavelengths_nm=wl, photons=int(got["photons"]), seconds=time.perf_counter() - t0,
                             n_host=float(fiber.n_host))
    table = _walked_exit_table(fiber, wl, nodes, bins, photons_per_row, seed, threads, max_group, t0)
    if key is not None:
        tablecache.store(key, {"T": table.T, "u_T": table.u_T, "k": table.k, "photons": np.int64(table.photons)})
    return table


#: the modules whose source is part of every exit table's cache key (the kernel and the table's builders)
EXIT_TABLE_MODULES = (
    "simulate.montecarlo.kernel", "simulate.montecarlo.tallies", "simulate.montecarlo.geometry",
    "simulate.montecarlo.scatter", "simulate.montecarlo.rng", "simulate.montecarlo.vecmath",
    "simulate.montecarlo.transport", "simulate.montecarlo.accuracy", "simulate.montecarlo.rows",
    "simulate.fiber.bssrdf", "simulate.fiber.spectral", "simulate.fiber.model", "simulate.fiber.farfield",
    "simulate.media.medium", "simulate.optics.mie", "simulate.optics.phase", "simulate.optics.fresnel",
)


def plain_fiber(fiber: Any) -> Any:
    """``fiber`` with its :class:`CachedMedium` unwrapped (the dataclass a cache key hashes).

    Parameters
    ----------
    fiber : Fiber
        Any fiber.

    Returns
    -------
    Fiber
        The fiber with its own medium.
    """
    import dataclasses

    return dataclasses.replace(fiber, medium=fiber.medium.medium) if isinstance(fiber.medium, CachedMedium) else fiber


def exit_table_key(fiber: Any, wavelengths_nm: Any, w_t: Any, bins: tuple[int, int], photons_per_row: int,
                   seed: int, max_group: int) -> str | None:
    """The disk-cache key of :func:`exit_table` (:mod:`simulate.fiber.tablecache`).

    The key holds the fiber (its dye included: this table is not white), wavelengths, nodes, bins, photons
    per row, seed, chunking and the code. The threads are not in it (same rows).

    Parameters
    ----------
    fiber : Fiber
        The fiber (a :class:`CachedMedium` is unwrapped first).
    wavelengths_nm : array_like
        Wavelengths of the table (nm).
    w_t : array_like
        The table's ``w_t`` nodes.
    bins : tuple of int
        Local exit bins ``(n_mu, n_phi)``.
    photons_per_row : int
        Photons launched per row.
    seed : int
        Random seed of the table.
    max_group : int
        Largest wavelength group of one walk.

    Returns
    -------
    str or None
        The key; None when the cache is off or the medium has no canonical form.
    """
    if not tablecache.enabled():
        return None
    inputs = {"fiber": plain_fiber(fiber), "wavelengths_nm": np.asarray(wavelengths_nm, float),
              "w_t": np.asarray(w_t, float), "bins": (int(bins[0]), int(bins[1])),
              "photons_per_row": int(photons_per_row), "seed": int(seed), "max_group": int(max_group)}
    try:
        return tablecache.content_key("exittable", inputs, EXIT_TABLE_MODULES)
    except TypeError as exc:
        log.warning("exit table: not cached (%s)", exc)
        return None


def _walked_exit_table(fiber: Any, wl: np.ndarray, nodes: np.ndarray, bins: tuple[int, int], photons_per_row: int,
                       seed: int, threads: int | None, max_group: int, t0: float) -> ExitTable:
    """:func:`exit_table` walked (no cache)."""
    from simulate import fiber as fiber_mod

    fiber = cached(fiber)
    T: np.ndarray | None = None
    u_T = np.zeros(0)
    photons, ks = 0, None
    for i, wt in enumerate(nodes):
        tab = fiber_mod.bssrdf_table(fiber, float(wt), wl, n_mu=bins[0], n_phi=bins[1],
                                     photons_per_row=photons_per_row, seed=int(seed) * 1_000_003 + 104_729 * i,
                                     threads=threads, max_group=max_group)
        if T is None:   # filled in place: no per-node copies of a table of ~10^8 bytes
            T = np.empty((nodes.size,) + tab["T"][:, :, 0].shape)
            u_T = np.empty_like(T)
        T[i] = tab["T"][:, :, 0]
        u_T[i] = tab["u_T"][:, :, 0]
        photons += int(tab["photons"])
        ks = tab["k"]
    assert T is not None
    T = _symmetrised(T)
    u_T /= math.sqrt(2.0)
    return ExitTable(w_t=nodes, T=T, u_T=u_T, k=np.asarray(ks), radius_um=fiber.radius_um,
                     wavelengths_nm=wl, photons=photons, seconds=time.perf_counter() - t0,
                     n_host=float(fiber.n_host))


def merged(a: ExitTable, b: ExitTable, per_row_a: int, per_row_b: int) -> ExitTable:
    """The exit table of the photons of ``a`` and ``b`` together (independent streams, same grid).

    Means weighted by the photons per row, ``u = sqrt(p_a^2 u_a^2 + p_b^2 u_b^2) / (p_a + p_b)``.

    Parameters
    ----------
    a, b : ExitTable
        The two tables.
    per_row_a, per_row_b : int
        Their photons per row.

    Returns
    -------
    ExitTable
        The pooled table.
    """
    n = float(per_row_a + per_row_b)
    wa, wb = per_row_a / n, per_row_b / n
    return dataclasses_replace(a, T=wa * a.T + wb * b.T, u_T=np.sqrt((wa * a.u_T) ** 2 + (wb * b.u_T) ** 2),
                               photons=a.photons + b.photons, seconds=a.seconds + b.seconds)


#: per-row photons of every exit-table round never fall below this (a round of a few photons per
#: row would measure nothing)
MIN_PHOTONS_PER_ROW = 50
#: at most this many rounds of :func:`controlled_halves` (the first measures, the second lands)
MAX_ROUNDS = 4
#: seed stride between rounds: round ``m`` of half ``h`` uses ``2 seed + h + ROUND_SEED_STRIDE m``
#: (distinct from the first round of every seed below 10^6)
ROUND_SEED_STRIDE = 2_000_000


def controlled_halves(fiber: Any, wavelengths_nm: Any, beta_of: Any, target_rel_err: float, *, per_row: int,
                      seed: int = 0, threads: int | None = None, max_photons_per_row: int | None = None,
                      ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """``beta, u_beta`` from two independent exit tables grown until ``beta`` meets the target error.

    The quantity the user asked an error for is what the caller makes of the tables --
    ``beta_of(table) -> [N, L]`` (a summation over rows, nodes, warp/weft and structure): its
    error, not the tables', is the target. Each round adds photons per row to both halves (seeds
    ``2 seed + h + ROUND_SEED_STRIDE m``), then ``beta`` is the mean of the halves' ``beta_of``
    and ``u_beta = |beta_1 - beta_2| / 2`` (one degree of freedom per value; its RMS over many
    values is the error read), :func:`simulate.montecarlo.accuracy.relative_error` of them the
    error reached. The first round uses ``per_row``; if the error is above the target the next
    adds photons to ``(rel / target)^2 SAFETY`` times those done (error ~ 1/sqrt(N)).

    Parameters
    ----------
    fiber : Fiber
        The fiber.
    wavelengths_nm : array_like
        Vacuum wavelengths (nm).
    beta_of : callable
        ``beta_of(table) -> [N, L]``, what the caller makes of a table.
    target_rel_err : float
        Target relative standard error of ``beta``.
    per_row : int
        Photons per row of the first round.
    seed : int
        Random seed.
    threads : int, optional
        Threads (results do not depend on it).
    max_photons_per_row : int, optional
        Budget per row of each half.

    Returns
    -------
    beta, u_beta : numpy.ndarray
        ``[N, L]`` the halves' mean and its error.
    info : dict
        ``rounds``, ``photons``, ``photons_per_row`` (both halves) and ``rel_err``.
    """
    from simulate.montecarlo.accuracy import SAFETY, relative_error

    wl = np.atleast_1d(np.asarray(wavelengths_nm, float))
    fiber = cached(fiber)
    limit = max_photons_per_row or 10**9
    tables: list[ExitTable | None] = [None, None]
    done, rows, rel = 0, max(int(per_row), MIN_PHOTONS_PER_ROW), math.inf
    rounds: list[dict[str, Any]] = []
    beta = u_beta = np.zeros(0)
    for m in range(MAX_ROUNDS):
        t0 = time.perf_counter()
        for h in range(2):
            new = exit_table(fiber, wl, photons_per_row=rows, seed=2 * int(seed) + h + ROUND_SEED_STRIDE * m,
                             threads=threads)
            old = tables[h]
            tables[h] = new if old is None else merged(old, new, done, rows)
        done += rows
        t1 = time.perf_counter()
        betas = [beta_of(t) for t in tables]
        beta = 0.5 * (betas[0] + betas[1])
        u_beta = 0.5 * np.abs(betas[0] - betas[1])
        rel = relative_error(beta, u_beta)
        rounds.append({"photons_per_row": 2 * done, "rel_err": rel, "exit_table_seconds": t1 - t0,
                       "layer_table_seconds": time.perf_counter() - t1})
        if rel <= target_rel_err or done >= limit:
            break
        rows = min(max(int(math.ceil(done * ((rel / target_rel_err) ** 2 * SAFETY - 1.0))), MIN_PHOTONS_PER_ROW),
                   limit - done)
    photons = sum(t.photons for t in tables if t is not None)
    return beta, u_beta, {"rounds": rounds, "photons": photons, "photons_per_row": 2 * done, "rel_err": rel}
