"""Compiled shading of the fibre-assembly tracer: what a ray does at a yarn hit.

One module for one compiled kernel (:func:`shade_groups`; :func:`shade` is its one-group case) and the
small compiled helpers it inlines: the helpers are the loop's events in their order and private to it (the
kernel cache keys a kernel on the modules it imports, so a split would cache correctly; it would make the
helpers public names for no other user).

:func:`shade_groups` scatters every hit ray of a wavefront once and prepares its next-event
contributions. Its inputs are packed as the Monte Carlo kernel packs its own
(:class:`simulate.montecarlo.kernel.KernelInputs`): :class:`ShadeInputs` (the mesh, the
material and the yarn table: fixed for a run) and :class:`ShadeOutputs` (per wavefront), both
NamedTuples of arrays and scalars that numba passes as one argument. The surface term is
:mod:`simulate.optics.microfacet`'s compiled Cook-Torrance (one implementation for the models
and the tracers).

The events of a hit, in their order, one inlined helper each (``inline="always"``: numba inlines
them in its own IR, so the loop compiles as one piece):

* :func:`_hit_frame`, :func:`_incidence`: the local frame at the hit and where the light comes from
  (shading normals, interpenetration);
* :func:`_shade_lambert`: a Lambertian material's next-event term and continuation;
* a fiber material (:func:`_shade_fiber`): the table row (:func:`_table_row`), the point of the fiber
  layer met (:func:`_layer_hit`), the entry into the volume (:func:`_volume_entry`), the surface's
  share (:func:`_surface_share`), the surface's next-event term (:func:`_nee_surface`); then either
  the cell-BRDF approximation (:func:`_cell_brdf_albedo`, :func:`_shade_cell_brdf`) or the volume:
  a reflection sample on the layer (:func:`_layer_reflection`), an exit drawn from the row and placed
  on the tube (:func:`_sample_exit`), its next-event term (:func:`_nee_exit`) and the continuing ray
  (:func:`_continue_fiber`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from simulate.optics.fresnel import fresnel_unpolarized
from simulate.optics.microfacet import cook_torrance_cos_local, unit3
from simulate.raytrace.materials import K_FIBER, K_FIBER_BRDF, K_LAMBERT
from simulate.raytrace.scene import EPS_UM

__all__ = ["ShadeInputs", "ShadeOutputs", "shade", "shade_groups", "new_outputs"]


class ShadeInputs(NamedTuple):
    """What every wavefront of a run shares: mesh arrays, material, yarn table, detectors."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    vertex_s: np.ndarray
    vertex_phi: np.ndarray
    face_yarn: np.ndarray
    vertex_base: np.ndarray
    n_s: np.ndarray
    yarn_length: np.ndarray
    sides: int
    run_axis: np.ndarray
    kind: int
    rho: np.ndarray
    m: float
    n_host: float
    albedo_tab: np.ndarray
    T: np.ndarray
    cdf: np.ndarray
    cell_sum: np.ndarray
    c_bar: np.ndarray
    tau: np.ndarray
    nodes: np.ndarray
    dpsi: float
    n_psi: int
    n_v: int
    n_mu: int
    n_phi: int
    v_edges: np.ndarray
    off_tot: np.ndarray
    off_bar: np.ndarray
    detectors: np.ndarray
    twist_c: np.ndarray
    twist_s: np.ndarray
    r_yarn: float
    face_base: np.ndarray
    face_normals: bool
    layer_d: float = 0.0
    axial_shift: bool = False
    defer_nee: bool = False
    """A fiber's next-event contributions deferred (:class:`ShadeOutputs`' ``nee_row``, ``nee_scale``)."""


class ShadeOutputs(NamedTuple):
    """Per hit ray, what its shading writes: the continuation, the next-event terms and the albedo.

    Per hit ray: the continuing ray (origin, direction, spectral weight; a zero row is dead),
    next-event origins, contributions and flags (event 0: surface, 1: volume exit), local albedo.

    With ``defer_nee`` (:class:`ShadeInputs`; a fiber material) ``nee_c`` is not written: a flagged
    contribution is ``weight[i, k] * T2[nee_row, k] * nee_scale`` with ``T2`` the table's rows
    (``T.reshape(-1, L)``), or ``weight[i, k] * nee_scale`` where ``nee_row`` is -1 (the surface term):
    the same products, computed by the tracer only for the candidates it keeps.
    """

    out_o: np.ndarray
    out_d: np.ndarray
    out_w: np.ndarray
    nee_o: np.ndarray
    nee_c: np.ndarray
    nee_need: np.ndarray
    hit_albedo: np.ndarray
    out_prim: np.ndarray
    nee_row: np.ndarray
    nee_scale: np.ndarray
    out_row: np.ndarray
    """A fiber material's continuation: ``out_w = weight * T2[out_row] * out_scale`` (a volume exit), or
    ``weight * out_scale`` where ``out_row`` is -1 (a reflection; 0: a dead ray) -- what a dye's re-weighting
    needs (:mod:`simulate.raytrace.reweight`)."""
    out_scale: np.ndarray


def new_outputs(n: int, n_detectors: int, n_wavelengths: int) -> ShadeOutputs:
    """Output arrays for ``n`` hit rays.

    Parameters
    ----------
    n : int
        Hit rays.
    n_detectors : int
        Detector directions.
    n_wavelengths : int
        Spectral size.

    Returns
    -------
    ShadeOutputs
        Uninitialised arrays but for the flags (cleared).
    """
    return ShadeOutputs(np.empty((n, 3)), np.empty((n, 3)), np.empty((n, n_wavelengths)), np.zeros((n, 2, 3)),
                        np.zeros((n, 2, n_detectors, n_wavelengths)), np.zeros((n, 2, n_detectors), dtype=np.bool_),
                        np.zeros(n), np.full(n, -1, dtype=np.int64), np.zeros((n, 2, n_detectors), dtype=np.int64),
                        np.zeros((n, 2, n_detectors)), np.full(n, -1, dtype=np.int64), np.zeros(n))


@numba.njit(cache=True)
def _interp(a, x):
    """Linear interpolation of a table ``a`` on a uniform grid over [0, 1] (clamped)."""
    n = a.shape[0]
    t = min(max(x, 0.0), 1.0) * (n - 1)
    i = min(int(t), n - 2)
    f = t - i
    return a[i] * (1.0 - f) + a[i + 1] * f


@numba.njit(cache=True)
def _tube_point(s, phi, yarn, tube, periodic, face_base):
    """Point, normal and tangent of the tube mesh at ``(s, phi)``.

    Point, normal and tangent of the tube mesh at (s, phi): the mesh's own triangles; with a
    non-empty ``face_base`` also the triangle's index and its outward geometric normal. ``periodic = False``
    (an open fiber of a felt, :mod:`simulate.geometry.felt`): ``s`` is clamped to the tube's ends. ``tube``:
    the mesh's ``(vertices, normals, tangents, vertex_base, n_s, yarn_length, sides)`` (:class:`ShadeInputs`).
    """
    vertices, normals, tangents, vertex_base, n_s, yarn_length, sides = tube
    L = yarn_length[yarn]
    ns = n_s[yarn]
    if periodic:
        s = s % L
    else:
        s = min(max(s, 0.0), L)
    phi = phi % (2.0 * math.pi)
    xs = s / L * ns
    xp = phi / (2.0 * math.pi) * sides
    i_s = min(int(xs), ns - 1)
    i_p = min(int(xp), sides - 1)
    fs = xs - i_s
    fp = xp - i_p
    base = vertex_base[yarn]
    v00 = base + i_s * (sides + 1) + i_p
    v10 = v00 + (sides + 1)
    v11 = v10 + 1
    v01 = v00 + 1
    if fs >= fp:
        a, b, c = v00, v10, v11
        wa, wb, wc = 1.0 - fs, fs - fp, fp
        second = 0
    else:
        a, b, c = v00, v11, v01
        wa, wb, wc = 1.0 - fp, fs, fp - fs
        second = 1
    # tuples, not arrays: no allocation per call (three calls per volume exit)
    p = (wa * vertices[a, 0] + wb * vertices[b, 0] + wc * vertices[c, 0],
         wa * vertices[a, 1] + wb * vertices[b, 1] + wc * vertices[c, 1],
         wa * vertices[a, 2] + wb * vertices[b, 2] + wc * vertices[c, 2])
    n = (wa * normals[a, 0] + wb * normals[b, 0] + wc * normals[c, 0],
         wa * normals[a, 1] + wb * normals[b, 1] + wc * normals[c, 1],
         wa * normals[a, 2] + wb * normals[b, 2] + wc * normals[c, 2])
    t = (wa * tangents[a, 0] + wb * tangents[b, 0] + wc * tangents[c, 0],
         wa * tangents[a, 1] + wb * tangents[b, 1] + wc * tangents[c, 1],
         wa * tangents[a, 2] + wb * tangents[b, 2] + wc * tangents[c, 2])
    g = (0.0, 0.0, 0.0)
    face = -1
    if face_base.shape[0] > 0:
        # the contract's faces wind (v00, v11, v10) and (v00, v01, v11): (a, c, b) here, outward
        face = face_base[yarn] + 2 * (i_s * sides + i_p) + second
        e1x, e1y, e1z = vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1], vertices[c, 2] - vertices[a, 2]
        e2x, e2y, e2z = vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1], vertices[b, 2] - vertices[a, 2]
        g = unit3(e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x)
    return p, n, t, g, face


@numba.njit(cache=True)
def _twist(tx, ty, tz, bx, by, bz, c, s):
    """The fiber frame of a twisted yarn at a point.

    The fiber frame of a twisted yarn: ``t_f = cos(alpha) T + s sin(alpha) (T x n)`` (``s = +1``
    Z, ``-1`` S, :mod:`simulate.fabric.structure`); with ``T x n = -b``: ``t_f = c t - s' b``,
    ``b_f = n x t_f = c b + s' t`` (``s' = s sin(alpha)``).
    """
    return c * tx - s * bx, c * ty - s * by, c * tz - s * bz, c * bx + s * tx, c * by + s * ty, c * bz + s * tz


@numba.njit(cache=True)
def _layer_point(uy, uz, d):
    """Where a ray of the beam meets the top layer of a yarn's fibers (two-dimensional, fiber radius 1).

    The layer: parallel unit circles at ``(j d, 0)`` in the cross-section plane ``(b, n)`` (``d = 2``
    touching). ``(uy, uz)`` is the ray's unit propagation direction in that plane (``uz < 0``: falling on
    the layer); the ray crosses ``z = 0`` at ``y0`` uniform over a period (a parallel beam). Returns the
    outward normal ``(ny, nz)`` of the point it meets first -- ``n(psi) = ny b + nz n`` -- and ``True``,
    or ``(0, 1, False)`` when it falls through a gap between the fibers (``d > 2``). The first hit along
    the ray is the first hit in the order of the circles along its run (they do not overlap).
    """
    y0 = (np.random.random() - 0.5) * d
    if uz > -1e-12:
        uz = -1e-12
    ye = y0 + uy / uz        # where the ray is at z = +1 ...
    yx = y0 - uy / uz        # ... and at z = -1
    step = 1 if uy >= 0.0 else -1
    if step > 0:
        j0 = int(math.floor((ye - 1.0) / d))
        j1 = int(math.ceil((yx + 1.0) / d))
    else:
        j0 = int(math.ceil((ye + 1.0) / d))
        j1 = int(math.floor((yx - 1.0) / d))
    count = min(abs(j1 - j0) + 1, 1000)
    j = j0
    for _ in range(count):
        qy = y0 - j * d
        b = uy * qy
        disc = b * b - (qy * qy - 1.0)
        if disc >= 0.0:
            t = -b - math.sqrt(disc)
            hy, hz = qy + t * uy, t * uz
            return hy, hz, True
        j += step
    return 0.0, 1.0, False


@numba.njit(cache=True)
def _layer_seen(vy, vz, py, pz, d):
    """Whether a point of the central fiber of a layer is seen from an in-plane direction.

    Whether the point ``(py, pz)`` of the central unit circle (outward normal the same) is seen from the
    in-plane direction ``(vy, vz)`` (not necessarily unit): it faces it, the direction rises above the layer
    and misses the neighbours at ``(+-d, 0)`` (for a rising ray only they can block:
    :mod:`simulate.fabric.fiberlayer`).
    """
    if vz <= 0.0 or vy * py + vz * pz <= 0.0:
        return False
    nrm = math.sqrt(vy * vy + vz * vz)
    vy /= nrm
    vz /= nrm
    for c in (-d, d):
        qy = py - c
        cc = qy * qy + pz * pz - 1.0
        b = vy * qy + vz * pz
        if cc > 0.0 and b < 0.0 and b * b - cc > 0.0:
            return False
    return True


@numba.njit(cache=True)
def _out_factor(wx, wy, wz, gx, gy, gz, nx, ny, nz):
    """Exit half of the adjoint shading-normal factor (docs/physics.md 6).

    ``|w.N_g| / |w.N_s|``,
    0 unless ``w`` is above both the geometric and the shading horizon.
    """
    cg = wx * gx + wy * gy + wz * gz
    cs = wx * nx + wy * ny + wz * nz
    if cg <= 0.0 or cs <= 0.0:
        return 0.0
    return cg / cs


@numba.njit(cache=True)
def _frame(n0, n1, n2, t0, t1, t2):
    """Orthonormal (t, b, n) from an interpolated normal and tangent; b = n x t."""
    nx, ny, nz = unit3(n0, n1, n2)
    d = t0 * nx + t1 * ny + t2 * nz
    tx, ty, tz = unit3(t0 - d * nx, t1 - d * ny, t2 - d * nz)
    bx = ny * tz - nz * ty
    by = nz * tx - nx * tz
    bz = nx * ty - ny * tx
    return tx, ty, tz, bx, by, bz, nx, ny, nz


@numba.njit(cache=True)
def _pick(cdf, u):
    """Index i with cdf[i-1] <= u < cdf[i] (cdf increasing, last = total)."""
    lo = 0
    hi = cdf.shape[0] - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if cdf[mid] > u:
            hi = mid
        else:
            lo = mid + 1
    return lo


@numba.njit(cache=True)
def _sample_ct(lt, lb, ln, m, n_host, a_s, p_refl):
    """Reflected local direction and weight factor of the surface branch.

    Reflected local direction and weight factor of the surface branch (Beckmann sampling;
    ``m = 0``: the specular Fresnel mirror).
    """
    if m > 0.0:
        u1 = np.random.random()
        u2 = np.random.random()
        tan2 = -(m * m) * math.log(1.0 - u1)
        ch = 1.0 / math.sqrt(1.0 + tan2)
        sh = math.sqrt(tan2) * ch
        ph = 2.0 * math.pi * u2
        hx, hy, hz = sh * math.cos(ph), sh * math.sin(ph), ch
        ih = lt * hx + lb * hy + ln * hz
        ot, ob, on = 2.0 * ih * hx - lt, 2.0 * ih * hy - lb, 2.0 * ih * hz - ln
        if on > 0.0 and ih > 0.0:
            g = min(1.0, min(2.0 * ch * on / ih, 2.0 * ch * ln / ih))
            return ot, ob, on, g * fresnel_unpolarized(ih, 1.0, n_host) * ih / (ln * ch) / p_refl
        return ot, ob, on, 0.0
    return -lt, -lb, ln, a_s / p_refl


@numba.njit(cache=True)
def _table_bin(w, frame, mu, sx, sb, n_mu, n_phi):
    """A detector's direction binned in the table's frame, with the bin's projected solid angle.

    A detector's direction ``w`` binned in the table's frame (mirrors applied; they are involutions)
    and the bin's projected solid angle ``Omega_proj``.
    """
    wx, wy, wz = w
    tx, ty, tz, bx, by, bz, _, _, _ = frame
    dphi = 2.0 * math.pi / n_phi
    ph = math.atan2(wx * bx + wy * by + wz * bz, wx * tx + wy * ty + wz * tz)
    if sx < 0.0:
        ph = math.pi - ph
    if sb < 0.0:
        ph = -ph
    ph = (ph + math.pi) % (2.0 * math.pi)
    jm = min(int(mu * n_mu), n_mu - 1)
    jp = min(int(ph / dphi), n_phi - 1)
    return jm, jp, 0.5 * (((jm + 1.0) / n_mu) ** 2 - (jm / n_mu) ** 2) * dphi


@numba.njit(cache=True)
def _shifted_bin(w, frame, sx, sb, shift, n_mu, n_phi):
    """A detector's direction binned in the table's frame of a row whose exits are shifted along the axis.

    A detector's direction ``w`` binned in the table's frame when the row's exits are shifted along the
    axis by ``shift`` (:func:`_bin_direction`): the bin of the direction's pre-image, the bin's projected
    solid angle, and ``ratio`` = the pre-image's cosine from the normal over the direction's (the
    density is uniform in projected solid angle at the pre-image; the shift keeps solid angle).
    ``ratio`` 0: the direction has no pre-image (it would need ``|w_t| >= 1`` in the row).
    """
    wx, wy, wz = w
    tx, ty, tz, bx, by, bz, nx, ny, nz = frame
    dphi = 2.0 * math.pi / n_phi
    wt = sx * (wx * tx + wy * ty + wz * tz)
    wb = sb * (wx * bx + wy * by + wz * bz)
    wn = wx * nx + wy * ny + wz * nz
    ratio = 1.0
    if shift != 0.0:
        wt2 = wt - shift
        perp = math.sqrt(max(1.0 - wt * wt, 0.0))
        if abs(wt2) >= 1.0 or perp <= 0.0:
            return 0, 0, 1.0, 0.0
        ratio = math.sqrt(1.0 - wt2 * wt2) / perp
        wt = wt2
        wb *= ratio
    mu = wn * ratio
    ph = (math.atan2(wb, wt) + math.pi) % (2.0 * math.pi)
    jm = min(int(mu * n_mu), n_mu - 1)
    jp = min(int(ph / dphi), n_phi - 1)
    return jm, jp, 0.5 * (((jm + 1.0) / n_mu) ** 2 - (jm / n_mu) ** 2) * dphi, ratio


@numba.njit(cache=True)
def _bin_direction(out_d, i, cell, n_mu, n_phi, sx, sb, frame, shift=0.0):
    """Draw a direction in a table cell's direction bin, shifted along the fiber axis, into ``out_d[i]``.

    A direction uniform in projected solid angle within a table cell's direction bin, shifted along
    the fiber axis by ``shift`` (its component along ``t`` in the table's frame moved by ``shift``, its
    azimuth about the axis kept: a map that keeps solid angle), mirrored back into the local frame
    ``(t, b, n)``, written to ``out_d[i]``. Returns False (nothing written) when the shifted direction
    does not exist (``|w_t| >= 1``). Why the shift: docs/physics.md 6, "Axial shift".
    """
    tx, ty, tz, bx, by, bz, nx, ny, nz = frame
    iphi = cell % n_phi
    imu = (cell // n_phi) % n_mu
    mlo = imu / n_mu
    mhi = (imu + 1.0) / n_mu
    mu = math.sqrt(mlo * mlo + (mhi * mhi - mlo * mlo) * np.random.random())
    ph = -math.pi + (iphi + np.random.random()) * 2.0 * math.pi / n_phi
    st = math.sqrt(max(1.0 - mu * mu, 0.0))
    ct, sp = st * math.cos(ph), st * math.sin(ph)
    if shift != 0.0:
        ct2 = ct + shift
        perp = math.sqrt(sp * sp + mu * mu)
        if abs(ct2) >= 1.0 or perp <= 0.0:
            return False
        f = math.sqrt(1.0 - ct2 * ct2) / perp
        ct, sp, mu = ct2, sp * f, mu * f
    ct *= sx
    sp *= sb
    out_d[i, 0] = ct * tx + sp * bx + mu * nx
    out_d[i, 1] = ct * ty + sp * by + mu * ny
    out_d[i, 2] = ct * tz + sp * bz + mu * nz
    return True


@numba.njit(cache=True)
def _reflect_out(out_d, out_w, weight, hit, surf):
    """The surface branch's continuation of ``hit``; returns the weight factor.

    The surface branch's continuation of ``hit``: sampled reflection, weight factor and the adjoint
    shading-normal factor applied (0 below the geometric horizon). Returns the factor.
    """
    i, g, frame, inc, corr_in = hit
    gx, gy, gz = g
    tx, ty, tz, bx, by, bz, nx, ny, nz = frame
    lt, lb, ln = inc
    m, n_host, a_s, p_refl = surf
    ot, ob, on, wgt = _sample_ct(lt, lb, ln, m, n_host, a_s, p_refl)
    out_d[i, 0] = ot * tx + ob * bx + on * nx
    out_d[i, 1] = ot * ty + ob * by + on * ny
    out_d[i, 2] = ot * tz + ob * bz + on * nz
    wgt *= corr_in * _out_factor(out_d[i, 0], out_d[i, 1], out_d[i, 2], gx, gy, gz, nx, ny, nz)
    for k in range(weight.shape[1]):
        out_w[i, k] = weight[i, k] * wgt
    return wgt


def shade(seed, prim, bu, bv, pos, dirs, weight, inp, out):
    """Scatter every hit ray once and prepare its next-event contributions.

    The one-group case of :func:`shade_groups`, which it calls (towards ``inp.detectors``): a compiled
    function of its own would link and optimise the whole shading loop once more, for no other use.

    ``out_w`` rows of zeros are dead rays. ``nee_c[i, e, d, :]`` is the intensity per unit
    incident power towards detector ``d`` of event ``e`` (0: surface, 1: volume exit) from
    origin ``nee_o[i, e]``, to be multiplied by the visibility; it is written only where
    ``nee_need[i, e, d]`` is set (the rest of ``nee_c`` is left as it was).

    Parameters
    ----------
    seed : int
        The random state of the call.
    prim : numpy.ndarray
        ``[M]`` the hit triangle of each ray.
    bu, bv : numpy.ndarray
        ``[M]`` barycentric coordinates of the hit on it.
    pos : numpy.ndarray
        ``[M, 3]`` hit points.
    dirs : numpy.ndarray
        ``[M, 3]`` the rays' directions.
    weight : numpy.ndarray
        ``[M, L]`` the rays' spectral weights.
    inp : ShadeInputs
        The run's mesh, material and table arrays.
    out : ShadeOutputs
        Written row by row (:func:`new_outputs`).
    """
    shade_groups(np.array([seed], np.int64), np.array([0, prim.shape[0]], np.int64), prim, bu, bv, pos, dirs,
                 weight, inp, np.ascontiguousarray(inp.detectors[None]), out)


@numba.njit(cache=True, nogil=True)
def shade_groups(seeds, cuts, prim, bu, bv, pos, dirs, weight, inp, detectors, out):
    """:func:`shade` of a wavefront of several groups (rotations), each towards its own detectors.

    The rows ``cuts[g]:cuts[g + 1]`` belong to group ``g`` (a rotation) and are scored towards
    ``detectors[g]`` from the random state ``seeds[g]``: the same as one :func:`shade` call per non-empty
    group on its slices, in one call (compiled).

    Parameters
    ----------
    seeds : numpy.ndarray
        ``int64[G]`` each group's random state.
    cuts : numpy.ndarray
        ``[G + 1]`` the groups' row bounds.
    prim : numpy.ndarray
        ``[M]`` the hit triangle of each ray.
    bu, bv : numpy.ndarray
        ``[M]`` barycentric coordinates of the hit on it.
    pos : numpy.ndarray
        ``[M, 3]`` hit points.
    dirs : numpy.ndarray
        ``[M, 3]`` the rays' directions.
    weight : numpy.ndarray
        ``[M, L]`` the rays' spectral weights.
    inp : ShadeInputs
        The run's mesh, material and table arrays.
    detectors : numpy.ndarray
        ``[G, D, 3]`` each group's detector directions.
    out : ShadeOutputs
        Written row by row.
    """
    hits = (prim, bu, bv, pos, dirs, weight)
    clampf = np.ones(weight.shape[1])
    for g in range(seeds.shape[0]):
        if cuts[g + 1] > cuts[g]:
            _shade_rows(seeds[g], cuts[g], cuts[g + 1], hits, inp, detectors[g], out, clampf)


# _nrt=False: compiled without reference counting (numba's option for code that allocates nothing). An
# inlined helper binds its arguments to its own variables, and with counting every array of a record
# argument (``inp``, ``out``) would be counted up and down at each call, in every hit.
@numba.njit(cache=True, nogil=True, _nrt=False)
def _shade_rows(seed, lo, hi, hits, inp, detectors, out, clampf):
    """:func:`shade` of the rows ``lo:hi`` of a wavefront's hits.

    :func:`shade` of the rows ``lo:hi`` of ``hits`` (``prim, bu, bv, pos, dirs, weight``) towards
    ``detectors``, from the random state ``seed``: each hit's events in turn (module docstring).
    ``clampf``: scratch of the cell-BRDF approximation's energy clamp, one value per wavelength.
    """
    prim, bu, bv, pos, dirs, weight = hits
    # numba keeps one random state per thread: seeding it here, from the chunk's own stream, makes
    # every call reproducible whatever thread runs it (no state is shared between calls)
    np.random.seed(seed)
    D = detectors.shape[0]
    for k in range(clampf.shape[0]):
        clampf[k] = 1.0
    for i in range(lo, hi):
        on_yarn, g, frame = _hit_frame(i, prim, bu, bv, inp, out)
        for e in range(2):
            for d in range(D):
                out.nee_need[i, e, d] = False
        lit, inside, corr_in, inc = _incidence(i, dirs, g, frame)
        if not lit:
            _kill(out.out_w, i, weight.shape[1])
            continue
        hit = (i, g, frame, inc, corr_in)
        _ray_origins(i, pos, g, out)
        if inp.kind == K_LAMBERT:
            _shade_lambert(hit, weight, inp, detectors, out)
        else:
            _shade_fiber(hit, inside, on_yarn, weight, inp, detectors, out, clampf)


# ----------------------------------------------------------------------------------- the events of a hit
# Inlined into _shade_rows by numba (inline="always", in its own IR): the hot values of a hit stay in
# registers as in one loop written out in a piece. A hit travels as the tuple ``hit = (i, g, frame, inc,
# corr_in)``: its row, the geometric normal, the shading frame (t, b, n) of the table, the incident
# direction in that frame and the adjoint shading-normal factor of the incidence.


@numba.njit(cache=True, inline="always")
def _kill(out_w, i, n_wavelengths):
    """The ray of row ``i`` ends (a zero weight row)."""
    for k in range(n_wavelengths):
        out_w[i, k] = 0.0


@numba.njit(cache=True, inline="always")
def _hit_frame(i, prim, bu, bv, inp, out):
    """The local geometry of hit ``i`` on its triangle: ``(on_yarn, g, frame)``.

    ``g``: the outward geometric normal (from the winding); ``frame``: the shading frame ``(t, b, n)``
    from the interpolated normal and tangent, twisted into the fiber's for a twisted yarn (the table's
    frame); ``on_yarn = (yarn, (ia, ib, ic, w0, w1, w2), yarn_frame, tw_s)``: the yarn, the triangle's
    vertices and barycentric weights, the yarn's own ``(t_x, t_y, b_x, b_y, b_z)`` (exit placement) and
    its twist. The row's continuation bookkeeping is reset (no table row, no scale).
    """
    vertices, normals, tangents = inp.vertices, inp.normals, inp.tangents
    f = prim[i]
    out.out_prim[i] = f
    out.out_row[i] = -1
    out.out_scale[i] = 0.0
    yarn = inp.face_yarn[f]
    ia, ib, ic = inp.faces[f, 0], inp.faces[f, 1], inp.faces[f, 2]
    w0 = 1.0 - bu[i] - bv[i]
    w1 = bu[i]
    w2 = bv[i]
    # geometric normal from the winding (outward)
    e1x = vertices[ib, 0] - vertices[ia, 0]
    e1y = vertices[ib, 1] - vertices[ia, 1]
    e1z = vertices[ib, 2] - vertices[ia, 2]
    e2x = vertices[ic, 0] - vertices[ia, 0]
    e2y = vertices[ic, 1] - vertices[ia, 1]
    e2z = vertices[ic, 2] - vertices[ia, 2]
    gx, gy, gz = unit3(e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x)
    if inp.face_normals:
        snx, sny, snz = gx, gy, gz
    else:
        snx = w0 * normals[ia, 0] + w1 * normals[ib, 0] + w2 * normals[ic, 0]
        sny = w0 * normals[ia, 1] + w1 * normals[ib, 1] + w2 * normals[ic, 1]
        snz = w0 * normals[ia, 2] + w1 * normals[ib, 2] + w2 * normals[ic, 2]
    tx, ty, tz, bx, by, bz, nx, ny, nz = _frame(
        snx, sny, snz,
        w0 * tangents[ia, 0] + w1 * tangents[ib, 0] + w2 * tangents[ic, 0],
        w0 * tangents[ia, 1] + w1 * tangents[ib, 1] + w2 * tangents[ic, 1],
        w0 * tangents[ia, 2] + w1 * tangents[ib, 2] + w2 * tangents[ic, 2])
    # the yarn's own frame (exit placement) and the fiber's (twist: the table's frame)
    yarn_frame = (tx, ty, bx, by, bz)
    tw_s = inp.twist_s[yarn]
    if tw_s != 0.0:
        tx, ty, tz, bx, by, bz = _twist(tx, ty, tz, bx, by, bz, inp.twist_c[yarn], tw_s)
    on_yarn = (yarn, (ia, ib, ic, w0, w1, w2), yarn_frame, tw_s)
    return on_yarn, (gx, gy, gz), (tx, ty, tz, bx, by, bz, nx, ny, nz)


@numba.njit(cache=True, inline="always")
def _incidence(i, dirs, g, frame):
    """Where the ray of row ``i`` comes from: ``(lit, inside, corr_in, (lt, lb, ln))``.

    Shading normals (Veach 1997, section 5.3; docs/physics.md 6): light scattered from w_in to
    w_out carries f |w_in.N_s| |w_out.N_g| / |w_in.N_g| (the adjoint of a camera tracer's
    f |w_in.N_s|), i.e. the local model times corr_in |w_out.N_g| / |w_out.N_s|. Light from
    outside that arrives below the shading horizon is absorbed (``lit`` False: the BSDF is 0 there, as in
    Mitsuba 3 and pbrt-v4), and nothing leaves below either horizon. Light from inside another yarn
    (``inside``: interpenetration) is mirrored about the tangent plane so the incidence is above it.
    ``(lt, lb, ln)``: the direction towards where the light came from, in the frame.
    """
    gx, gy, gz = g
    tx, ty, tz, bx, by, bz, nx, ny, nz = frame
    dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
    inside = dx * gx + dy * gy + dz * gz > 0.0
    # incident direction (towards where the light came from)
    ix, iy, iz = -dx, -dy, -dz
    dn = ix * nx + iy * ny + iz * nz
    corr_in = 1.0
    if not inside:
        if dn <= 0.0:
            return False, inside, 0.0, (0.0, 0.0, 1.0)
        corr_in = dn / max(-(dx * gx + dy * gy + dz * gz), 1e-12)
    else:
        ix, iy, iz = ix - 2.0 * dn * nx, iy - 2.0 * dn * ny, iz - 2.0 * dn * nz
    lt = ix * tx + iy * ty + iz * tz
    lb = ix * bx + iy * by + iz * bz
    ln = max(ix * nx + iy * ny + iz * nz, 1e-9)
    return True, inside, corr_in, (lt, lb, ln)


@numba.njit(cache=True, inline="always")
def _ray_origins(i, pos, g, out):
    """Write the origins of row ``i``'s continuing ray and surface next-event rays.

    The origins of row ``i``'s continuing ray and surface next-event rays: off the hit's triangle
    along the geometric normal (no re-hit of it).
    """
    gx, gy, gz = g
    out.out_o[i, 0] = pos[i, 0] + EPS_UM * gx
    out.out_o[i, 1] = pos[i, 1] + EPS_UM * gy
    out.out_o[i, 2] = pos[i, 2] + EPS_UM * gz
    for q in range(3):
        out.nee_o[i, 0, q] = out.out_o[i, q]


@numba.njit(cache=True, inline="always")
def _shade_lambert(hit, weight, inp, detectors, out):
    """Shade a hit on a Lambertian material.

    A Lambertian material: the next-event term towards every detector above both horizons, and a
    cosine-weighted continuation.
    """
    i, g, frame, _, corr_in = hit
    gx, gy, gz = g
    tx, ty, tz, _, _, _, nx, ny, nz = frame
    rho = inp.rho
    L = weight.shape[1]
    for d in range(detectors.shape[0]):
        co = detectors[d, 0] * nx + detectors[d, 1] * ny + detectors[d, 2] * nz
        cg = detectors[d, 0] * gx + detectors[d, 1] * gy + detectors[d, 2] * gz
        if co > 0.0 and cg > 0.0:
            out.nee_need[i, 0, d] = True
            for k in range(L):
                out.nee_c[i, 0, d, k] = weight[i, k] * rho[k] / math.pi * corr_in * cg
    # cosine-weighted continuation about the GEOMETRIC normal: the adjoint weight
    # f corr_in |w.N_g| / pdf is then rho corr_in wherever w is above the shading horizon
    # (importance sampling of the factor; about N_s it would carry |w.N_g| / |w.N_s|)
    tg = tx * gx + ty * gy + tz * gz
    ux, uy, uz = unit3(tx - tg * gx, ty - tg * gy, tz - tg * gz)
    vx, vy, vz = gy * uz - gz * uy, gz * ux - gx * uz, gx * uy - gy * ux
    u1 = np.random.random()
    u2 = np.random.random()
    r = math.sqrt(u1)
    ph = 2.0 * math.pi * u2
    cz = math.sqrt(max(1.0 - u1, 0.0))
    ox = r * math.cos(ph) * ux + r * math.sin(ph) * vx + cz * gx
    oy = r * math.cos(ph) * uy + r * math.sin(ph) * vy + cz * gy
    oz = r * math.cos(ph) * uz + r * math.sin(ph) * vz + cz * gz
    out.out_d[i, 0], out.out_d[i, 1], out.out_d[i, 2] = ox, oy, oz
    fac = corr_in if (cz > 0.0 and ox * nx + oy * ny + oz * nz > 0.0) else 0.0
    for k in range(L):
        out.out_w[i, k] = weight[i, k] * rho[k] * fac


@numba.njit(cache=True, inline="always")
def _shade_fiber(hit, inside, on_yarn, weight, inp, detectors, out, clampf):
    """Shade a hit on a fiber material: its events in order.

    A fiber material (a table of the yarn's volume, a Cook-Torrance surface): the events of the hit in
    their order -- the table row, the point of the fiber layer met, the entry into the volume, the
    surface's share, the surface next-event term, then either the cell-BRDF approximation's events or the
    volume's: a reflection sample, an exit drawn from the row and placed on the tube, its next-event
    term and the continuation.
    """
    i, _, _, inc, _ = hit
    row = _table_row(inc, inp)
    layer = inp.layer_d > 0.0 and inp.kind == K_FIBER and not inside
    lay = _layer_hit(inc, layer, inp.layer_d)
    vol, e_bar, wsum = _volume_entry(i, weight, inp, row, inside, lay)
    s_bar = 0.0
    if inp.kind == K_FIBER_BRDF:
        e_bar, s_bar = _cell_brdf_albedo(i, weight, inp, row, inc[2], wsum, clampf, out)
    surf = _surface_share(inside, lay, e_bar, inp)
    if surf[2] > 0.0 and inp.m > 0.0:
        _nee_surface(hit, weight, inp, detectors, out, lay)
    if inp.kind == K_FIBER_BRDF:
        _shade_cell_brdf(hit, weight, inp, detectors, out, row, surf, s_bar, clampf)
        return
    refl = _layer_reflection(inc, lay, surf, inp, vol)
    ex = _sample_exit(i, on_yarn, inp, out, row, vol)
    if ex[0] >= 0:
        _nee_exit(hit, weight, inp, detectors, out, row, vol, ex, refl[6])
    _continue_fiber(hit, weight, inp, out, row, surf, vol, ex, refl)


@numba.njit(cache=True, inline="always")
def _table_row(inc, inp):
    """The table row of the incidence, by stochastic linear interpolation in ``|w_t|`` and ``|a|``.

    The table row of the incidence, by stochastic linear interpolation in ``|w_t|`` and ``|a|``:
    ``(j, kr, k_max, sx, sb, shift)`` -- the ``|w_t|`` node, the azimuth row, the last row, the mirrors
    of the table's frame (signs of ``w_t`` and of the azimuth) and the axial shift of the row's exits.
    """
    lt, lb, ln = inc
    nodes, dpsi = inp.nodes, inp.dpsi
    sx = 1.0 if lt >= 0.0 else -1.0
    a = math.atan2(-lb, ln)
    sb = 1.0 if a >= 0.0 else -1.0
    at = abs(lt)
    j = nodes.shape[0] - 1
    for q in range(nodes.shape[0] - 1):
        if at < nodes[q + 1]:
            fr = (at - nodes[q]) / (nodes[q + 1] - nodes[q])
            j = q + 1 if np.random.random() < fr else q
            break
    xk = abs(a) / dpsi
    k0 = int(xk)
    k_max = inp.c_bar.shape[1] - 1
    if k0 >= k_max:
        kr = k_max
    else:
        kr = k0 + 1 if np.random.random() < xk - k0 else k0
    # axial shift (docs/physics.md 6, "Axial shift"): the row at node |w_t| = nodes[j] sends light that
    # crossed the fiber without scattering onto the cone of propagation component -nodes[j] along the
    # axis; this ray's is -|lt|. Its exits are moved along the axis by the difference (solid angle kept)
    shift = nodes[j] - at if inp.axial_shift else 0.0
    return j, kr, k_max, sx, sb, shift


@numba.njit(cache=True, inline="always")
def _layer_hit(inc, layer, layer_d):
    """The point of the yarn's top layer of fibers the ray meets.

    The point of the yarn's top layer of fibers the ray meets (FiberSurface(surface="fibers"),
    docs/physics.md 6): ``(layer, on_fiber, fy, fz, flb, fln)`` -- its normal ``fy b + fz n`` and the
    incident direction in the fiber's own frame; ``on_fiber`` False: a gap, straight into the volume.
    Without a layer (``layer`` False) the yarn's surface itself.
    """
    _, lb, ln = inc
    fy, fz, on_fiber = 0.0, 1.0, True
    flb, fln = lb, ln
    if layer:
        nrm2 = math.sqrt(lb * lb + ln * ln)
        fy, fz, on_fiber = _layer_point(-lb / nrm2, -ln / nrm2, layer_d)
        flb = fz * lb - fy * ln
        fln = max(fy * lb + fz * ln, 1e-9)
    return layer, on_fiber, fy, fz, flb, fln


@numba.njit(cache=True, inline="always")
def _volume_entry(i, weight, inp, row, inside, lay):
    """The volume's side of the hit: ``((total, cb, tr, entry), e_bar, wsum)``.

    The row gives where and how the light comes out (``total``: its sum; ``cb``: its cell-average
    ``c_bar``); the entry transmission is the exact smooth-interface 1 - F at this point (the row holds
    its cell-average ``tau = tr``), and none at all for light that is inside the yarn already
    (interpenetration): ``entry`` the factor of the row's exits. ``e_bar``: the volume's albedo at this
    hit, weighted by the ray's spectrum (``wsum`` its sum).
    """
    j, kr = row[0], row[1]
    n_cells = inp.n_psi * inp.n_v * inp.n_mu * inp.n_phi
    total = inp.cdf[j, kr, n_cells - 1]
    cb = inp.c_bar[j, kr]
    wsum = 0.0
    esum = 0.0
    for k in range(weight.shape[1]):
        wsum += weight[i, k]
        esum += weight[i, k] * inp.cell_sum[j, kr, k]
    tr = max(inp.tau[j, kr], 1e-12)
    on_fiber, fln = lay[1], lay[5]
    if inside or not on_fiber:
        entry = 1.0 / tr
    else:
        entry = (1.0 - fresnel_unpolarized(fln, 1.0, inp.n_host)) / tr
    e_bar = entry * esum / wsum / cb if (wsum > 0.0 and cb > 0.0) else 0.0
    return (total, cb, tr, entry), e_bar, wsum


@numba.njit(cache=True, inline="always")
def _offset_cell(kr, o, n_psi):
    """Row and offset index of entry cell ``o`` seen from row ``kr``.

    Row ``r`` and offset index of entry cell ``o`` seen from row ``kr`` (the tables hold ``|r|``;
    a negative row is the mirror image): ``(r, off)``.
    """
    r = kr + o
    off = o % n_psi if r >= 0 else (-o) % n_psi
    return r, off


@numba.njit(cache=True, inline="always")
def _cell_brdf_albedo(i, weight, inp, row, ln, wsum, clampf, out):
    """The cell-BRDF approximation's albedo at the hit point.

    The cell-BRDF approximation's albedo (``kind == K_FIBER_BRDF``): the fiber BRDF of the cell at the
    hit point -- light entering every lit cell A = B - o (local azimuth a + o dpsi) and leaving here.
    Returns ``(e_bar, s_bar)``, the volume's albedo and what the entry cells send here; writes the energy
    clamp per wavelength to ``clampf`` and the hit's albedo to ``hit_albedo``.
    """
    j, kr, k_max = row[0], row[1], row[2]
    n_psi, off_tot, off_bar = inp.n_psi, inp.off_tot, inp.off_bar
    h = n_psi // 2
    e_bar = 0.0
    a_max = 0.0
    a_s0 = _interp(inp.albedo_tab, ln) if inp.m > 0.0 else fresnel_unpolarized(ln, 1.0, inp.n_host)
    for k in range(weight.shape[1]):
        acc = 0.0
        for o in range(-h, n_psi - h):
            r, off = _offset_cell(kr, o, n_psi)
            if r > k_max or r < -k_max:
                continue
            acc += off_tot[j, abs(r), off, k]
        alb = acc / ln
        a_max = max(a_max, alb)
        # energy clamp: where surface + volume would exceed 1, the volume term is scaled
        # down to 1 - a_s (reported: the fraction of such hits and the unclamped albedo)
        clampf[k] = min(1.0, max(1.0 - a_s0, 0.0) / alb) if alb > 0.0 else 1.0
        e_bar += weight[i, k] * alb * clampf[k]
    e_bar = e_bar / wsum if wsum > 0.0 else 0.0
    s_bar = 0.0
    for o in range(-h, n_psi - h):
        r, off = _offset_cell(kr, o, n_psi)
        if r > k_max or r < -k_max:
            continue
        s_bar += off_bar[j, abs(r), off]
    out.hit_albedo[i] = a_max + a_s0
    return e_bar, s_bar


@numba.njit(cache=True, inline="always")
def _surface_share(inside, lay, e_bar, inp):
    """The surface branch's roughness, index, albedo and reflection probability.

    The surface branch: ``(m, n_host, a_s, p_refl)`` -- the roughness and index, the surface's albedo at
    the point met (0 in a gap) and the probability of continuing by reflection (in proportion to the
    surface's and the volume's albedos; 0 from inside, where no surface reflects).
    """
    on_fiber, fln = lay[1], lay[5]
    if not on_fiber:
        a_s = 0.0
    elif inp.m > 0.0:
        a_s = _interp(inp.albedo_tab, fln)
    else:
        a_s = fresnel_unpolarized(fln, 1.0, inp.n_host)
    if inside:
        p_refl = 0.0
    elif a_s + e_bar > 0.0:
        p_refl = a_s / (a_s + e_bar)
    else:
        p_refl = 1.0
    return inp.m, inp.n_host, a_s, p_refl


@numba.njit(cache=True, inline="always")
def _nee_surface(hit, weight, inp, detectors, out, lay):
    """Score the rough surface's next-event term towards every detector (event 0).

    The next-event term of the rough surface towards every detector (event 0): on the fibers, at the
    lit point, seen past the neighbours.
    """
    i, g, frame, inc, corr_in = hit
    gx, gy, gz = g
    tx, ty, tz, bx, by, bz, nx, ny, nz = frame
    lt, lb, ln = inc
    layer, _, fy, fz, flb, fln = lay
    m, n_host, layer_d = inp.m, inp.n_host, inp.layer_d
    for d in range(detectors.shape[0]):
        wx, wy, wz = detectors[d, 0], detectors[d, 1], detectors[d, 2]
        if wx * gx + wy * gy + wz * gz <= 0.0:
            continue
        ot = wx * tx + wy * ty + wz * tz
        ob = wx * bx + wy * by + wz * bz
        on = wx * nx + wy * ny + wz * nz
        if layer:
            if not _layer_seen(ob, on, fy, fz, layer_d):
                continue
            val = cook_torrance_cos_local(lt, flb, fln, ot, fz * ob - fy * on, fy * ob + fz * on, m, n_host)
        else:
            val = cook_torrance_cos_local(lt, lb, ln, ot, ob, on, m, n_host)
        if val > 0.0:
            val *= corr_in * (wx * gx + wy * gy + wz * gz) / on
            out.nee_need[i, 0, d] = True
            if inp.defer_nee:
                out.nee_row[i, 0, d] = -1
                out.nee_scale[i, 0, d] = val
                continue
            for k in range(weight.shape[1]):
                out.nee_c[i, 0, d, k] = weight[i, k] * val


@numba.njit(cache=True, inline="always")
def _shade_cell_brdf(hit, weight, inp, detectors, out, row, surf, s_bar, clampf):
    """Shade the cell-BRDF approximation's events of a hit.

    The cell-BRDF approximation's events (``kind == K_FIBER_BRDF``): with nothing sent here, a
    reflection or nothing; else one entry cell drawn in proportion to what it sends here, its next-event
    term (event 1, from the hit point) and the continuation -- a reflection, or an exit direction drawn
    from the cell's row.
    """
    i, g, frame, inc, corr_in = hit
    gx, gy, gz = g
    _, _, _, _, _, _, nx, ny, nz = frame
    ln = inc[2]
    j, kr, k_max, sx, sb, _ = row
    p_refl = surf[3]
    n_psi, n_v, n_mu, n_phi = inp.n_psi, inp.n_v, inp.n_mu, inp.n_phi
    T, cdf, off_bar = inp.T, inp.cdf, inp.off_bar
    out_d, out_w = out.out_d, out.out_w
    L = weight.shape[1]
    if s_bar <= 0.0:
        if np.random.random() < p_refl:
            _reflect_out(out_d, out_w, weight, hit, surf)
        else:
            _kill(out_w, i, L)
        return
    # one entry cell o, drawn in proportion to what it sends here
    h = n_psi // 2
    u = np.random.random() * s_bar
    acc = 0.0
    r_sel = 0
    off_sel = 0
    for o in range(-h, n_psi - h):
        r, off = _offset_cell(kr, o, n_psi)
        if r > k_max or r < -k_max:
            continue
        acc += off_bar[j, abs(r), off]
        r_sel = r
        off_sel = off
        if acc > u:
            break
    rr = abs(r_sel)
    sbe = sb if r_sel >= 0 else -sb
    p_o = off_bar[j, rr, off_sel] / s_bar
    seg = n_v * n_mu * n_phi
    for q in range(3):
        out.nee_o[i, 1, q] = out.nee_o[i, 0, q]
    for d in range(detectors.shape[0]):
        wx, wy, wz = detectors[d, 0], detectors[d, 1], detectors[d, 2]
        mu = wx * nx + wy * ny + wz * nz
        cg = wx * gx + wy * gy + wz * gz
        if mu <= 0.0 or cg <= 0.0:
            continue
        jm, jp, om = _table_bin((wx, wy, wz), frame, mu, sx, sbe, n_mu, n_phi)
        scale = corr_in * cg / (om * p_o * ln)
        out.nee_need[i, 1, d] = True
        for k in range(L):
            val = 0.0
            for iv in range(n_v):
                val += T[j, rr, ((off_sel * n_v + iv) * n_mu + jm) * n_phi + jp, k]
            out.nee_c[i, 1, d, k] = weight[i, k] * val * scale * clampf[k]
    if np.random.random() < p_refl:
        _reflect_out(out_d, out_w, weight, hit, surf)
        return
    c_lo = cdf[j, rr, off_sel * seg - 1] if off_sel > 0 else 0.0
    c_hi = cdf[j, rr, off_sel * seg + seg - 1]
    cell = _pick(cdf[j, rr], c_lo + (c_hi - c_lo) * np.random.random())
    t_cell = cdf[j, rr, cell] - (cdf[j, rr, cell - 1] if cell > 0 else 0.0)
    _bin_direction(out_d, i, cell, n_mu, n_phi, sx, sbe, frame)
    sc = s_bar / (ln * t_cell * (1.0 - p_refl)) if t_cell > 0.0 else 0.0
    sc *= corr_in * _out_factor(out_d[i, 0], out_d[i, 1], out_d[i, 2], gx, gy, gz, nx, ny, nz)
    for k in range(L):
        out_w[i, k] = weight[i, k] * T[j, rr, cell, k] * sc * clampf[k]


@numba.njit(cache=True, inline="always")
def _layer_reflection(inc, lay, surf, inp, vol):
    """One reflection sample on the fibers, for the continuation and for the light a neighbour masks.

    On the fibers: one reflection sample, for the continuation and for the light that a neighbour
    masks -- it meets that fiber and is taken into the yarn's volume. ``(layer, escape, wr, rt, mb, mn,
    entry_nee)``: whether it escapes past the neighbours, its weight, its direction in the yarn's frame
    and the entry factor of the volume's next-event term (the masked reflection added).
    """
    layer, on_fiber, fy, fz, flb, fln = lay
    a_s = surf[2]
    tr, entry = vol[2], vol[3]
    escape = False
    wr, rt, mb, mn = 0.0, 0.0, 0.0, 1.0
    entry_nee = entry
    if layer and on_fiber and a_s > 0.0:
        rt, rb_, rn, wr = _sample_ct(inc[0], flb, fln, inp.m, inp.n_host, a_s, 1.0)
        mb = rb_ * fz + rn * fy
        mn = rn * fz - rb_ * fy
        escape = _layer_seen(mb, mn, fy, fz, inp.layer_d)
        if not escape:
            entry_nee = entry + wr / tr
    return layer, escape, wr, rt, mb, mn, entry_nee


@numba.njit(cache=True, inline="always")
def _sample_exit(i, on_yarn, inp, out, row, vol):
    """Draw an exit from the row and place it on the tube.

    An exit drawn from the row (cell offset, v bin, direction bin) and placed on the tube:
    ``(cell, io, iv, e_face, e_frame, e_g)`` -- the cell (-1: the row sends nothing), its offset and v
    bin, the exit's triangle, shading frame (twisted as the hit's) and geometric normal. The exit's
    rays start off its triangle along the geometric normal (``nee_o[i, 1]``, no re-hit of it).
    """
    j, kr, _, sx, sb, _ = row
    total, cb = vol[0], vol[1]
    cell = -1
    if total > 0.0 and cb > 0.0:
        cell = _pick(inp.cdf[j, kr], np.random.random() * total)
    if cell < 0:
        return cell, 0, 0, -1, (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    yarn, bary, yarn_frame, tw_s = on_yarn
    ia, ib, ic, w0, w1, w2 = bary
    ytx, yty, ybx, yby, ybz = yarn_frame
    n_psi, n_v, n_mu, n_phi = inp.n_psi, inp.n_v, inp.n_mu, inp.n_phi
    tube = (inp.vertices, inp.normals, inp.tangents, inp.vertex_base, inp.n_s, inp.yarn_length, inp.sides)
    face_base = inp.face_base
    iv = (cell // (n_phi * n_mu)) % n_v
    io = cell // (n_phi * n_mu * n_v)
    o_signed = io if io <= n_psi // 2 else io - n_psi
    dps = sb * (o_signed + np.random.random() - 0.5) * inp.dpsi
    v_lo = inp.v_edges[iv]
    v_hi = inp.v_edges[iv + 1]
    vv = sx * (v_lo + (v_hi - v_lo) * np.random.random())
    # move on the tube: psi grows towards -b; v along +t (the fiber's frame)
    periodic = inp.run_axis[yarn] < 2
    s0 = w0 * inp.vertex_s[ia] + w1 * inp.vertex_s[ib] + w2 * inp.vertex_s[ic]
    f0 = w0 * inp.vertex_phi[ia] + w1 * inp.vertex_phi[ib] + w2 * inp.vertex_phi[ic]
    # d P / d phi ~ n x t-ish: find the phi direction from the neighbouring ring point
    q_p, q_n, q_t, q_g, q_f = _tube_point(s0, f0 + 1e-3, yarn, tube, periodic, face_base[:0])
    r_p, r_n, r_t, r_g, r_f = _tube_point(s0, f0, yarn, tube, periodic, face_base[:0])
    dpb = (q_p[0] - r_p[0]) * ybx + (q_p[1] - r_p[1]) * yby + (q_p[2] - r_p[2]) * ybz
    sgn = -1.0 if dpb > 0.0 else 1.0
    # s is x (warp), y (weft) or the arc length (a felt's fiber, run_axis 2)
    t_run = ytx if inp.run_axis[yarn] == 0 else (yty if inp.run_axis[yarn] == 1 else 1.0)
    if tw_s == 0.0:
        s1 = s0 + vv * t_run
        f1 = f0 + sgn * dps
    else:
        # twisted: the offset v t_f - r dps b_f on the surface, in the yarn's (t, b)
        c_a = inp.twist_c[yarn]
        d_t = vv * c_a - inp.r_yarn * dps * tw_s
        d_b = -vv * tw_s - inp.r_yarn * dps * c_a
        s1 = s0 + d_t * t_run
        f1 = f0 - sgn * d_b / inp.r_yarn
    e_p, e_n, e_t, e_g, e_face = _tube_point(s1, f1, yarn, tube, periodic, face_base)
    if inp.face_normals:
        e_n = e_g
    etx, ety, etz, ebx, eby, ebz, enx, eny, enz = _frame(e_n[0], e_n[1], e_n[2], e_t[0], e_t[1], e_t[2])
    if tw_s != 0.0:
        etx, ety, etz, ebx, eby, ebz = _twist(etx, ety, etz, ebx, eby, ebz, inp.twist_c[yarn], tw_s)
    for q in range(3):
        out.nee_o[i, 1, q] = e_p[q] + EPS_UM * e_g[q]
    return cell, io, iv, e_face, (etx, ety, etz, ebx, eby, ebz, enx, eny, enz), e_g


@numba.njit(cache=True, inline="always")
def _nee_exit(hit, weight, inp, detectors, out, row, vol, ex, entry_nee):
    """Score the volume exit's next-event term towards every detector (event 1).

    The next-event term of the volume exit ``ex`` towards every detector (event 1): the row's bin of
    each detector's direction (the pre-image of the axial shift) over the exit cell's marginal
    probability, ``entry_nee`` the entry factor. Deferred (``defer_nee``): the table row and the scale.
    """
    i, _, _, _, corr_in = hit
    j, kr, _, sx, sb, shift = row
    total, cb = vol[0], vol[1]
    _, io, iv, _, e_frame, e_g = ex
    _, _, _, _, _, _, enx, eny, enz = e_frame
    egx, egy, egz = e_g
    n_v, n_mu, n_phi, T, cdf = inp.n_v, inp.n_mu, inp.n_phi, inp.T, inp.cdf
    rows_per_node = T.shape[1] * T.shape[2]
    # marginal probability of the exit cell (offset, v): sum over its direction bins
    c_first = (io * n_v + iv) * n_mu * n_phi
    c_last = c_first + n_mu * n_phi - 1
    p_ov = cdf[j, kr, c_last] - (cdf[j, kr, c_first - 1] if c_first > 0 else 0.0)
    p_ov /= total
    for d in range(detectors.shape[0]):
        wx, wy, wz = detectors[d, 0], detectors[d, 1], detectors[d, 2]
        mu = wx * enx + wy * eny + wz * enz
        cg = wx * egx + wy * egy + wz * egz
        if mu <= 0.0 or cg <= 0.0:
            continue
        jm, jp, om, ratio = _shifted_bin((wx, wy, wz), e_frame, sx, sb, shift, n_mu, n_phi)
        if ratio <= 0.0:
            continue
        c2 = c_first + jm * n_phi + jp
        scale = entry_nee * corr_in * cg * ratio / (om * cb * p_ov)
        out.nee_need[i, 1, d] = True
        if inp.defer_nee:
            out.nee_row[i, 1, d] = j * rows_per_node + kr * T.shape[2] + c2
            out.nee_scale[i, 1, d] = scale
            continue
        for k in range(weight.shape[1]):
            out.nee_c[i, 1, d, k] = weight[i, k] * T[j, kr, c2, k] * scale


@numba.njit(cache=True, inline="always")
def _continue_fiber(hit, weight, inp, out, row, surf, vol, ex, refl):
    """Write the continuing ray of a fiber hit.

    The continuing ray of a fiber hit: a reflection (``p_refl``) -- sampled here, or the layer's sample
    when it escapes past the neighbours -- or the volume exit ``ex`` (a masked reflection enters the volume
    there too), or nothing.
    """
    i, g, frame, _, corr_in = hit
    gx, gy, gz = g
    tx, ty, tz, bx, by, bz, nx, ny, nz = frame
    j, kr, _, sx, sb, shift = row
    p_refl = surf[3]
    total, cb, tr, entry = vol
    cell, _, _, e_face, e_frame, e_g = ex
    layer, escape, wr, rt, mb, mn, _ = refl
    n_mu, n_phi, T, cdf = inp.n_mu, inp.n_phi, inp.T, inp.cdf
    out_d, out_w = out.out_d, out.out_w
    L = weight.shape[1]
    refl_drawn = np.random.random() < p_refl
    if refl_drawn and not layer:
        out.out_scale[i] = _reflect_out(out_d, out_w, weight, hit, surf)
    elif refl_drawn and escape:
        out_d[i, 0] = rt * tx + mb * bx + mn * nx
        out_d[i, 1] = rt * ty + mb * by + mn * ny
        out_d[i, 2] = rt * tz + mb * bz + mn * nz
        wgt = wr / p_refl * corr_in * _out_factor(out_d[i, 0], out_d[i, 1], out_d[i, 2], gx, gy, gz, nx, ny, nz)
        out.out_scale[i] = wgt
        for k in range(L):
            out_w[i, k] = weight[i, k] * wgt
    elif cell >= 0:
        if not _bin_direction(out_d, i, cell, n_mu, n_phi, sx, sb, e_frame, shift):
            _kill(out_w, i, L)
            return
        for q in range(3):
            out.out_o[i, q] = out.nee_o[i, 1, q]
        out.out_prim[i] = e_face
        p_c = (cdf[j, kr, cell] - (cdf[j, kr, cell - 1] if cell > 0 else 0.0)) / total
        if refl_drawn:     # reflected towards a neighbour: into the volume
            sc = wr / (p_refl * tr * cb * p_c)
        else:
            sc = entry / (cb * p_c * (1.0 - p_refl))
        _, _, _, _, _, _, enx, eny, enz = e_frame
        sc *= corr_in * _out_factor(out_d[i, 0], out_d[i, 1], out_d[i, 2], e_g[0], e_g[1], e_g[2], enx, eny, enz)
        out.out_row[i] = j * (T.shape[1] * T.shape[2]) + kr * T.shape[2] + cell
        out.out_scale[i] = sc
        for k in range(L):
            out_w[i, k] = weight[i, k] * T[j, kr, cell, k] * sc
    else:
        _kill(out_w, i, L)
