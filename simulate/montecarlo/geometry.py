"""Convex geometries of the Monte Carlo kernel: slab and circular cylinder.

Two shapes, both with an analytic distance to the boundary along a ray from inside
(docs/physics.md section 3). The outside index is 1, the inside index ``n``; any consistent
length unit may be used (the kernel only ever multiplies lengths by ``mu_t``).

``SLAB`` (``geom = [d]``)
    The layer ``-d <= z <= 0`` of infinite lateral extent; its top face ``z = 0`` faces
    the light (fabric frame: z = normal, up towards the source). From a point inside,
    moving along ``u``::

        s = -z / u_z           (u_z > 0, towards the top face,    outward normal +z)
        s = (-d - z) / u_z     (u_z < 0, towards the bottom face, outward normal -z)
        s = inf                (u_z = 0)

``CYLINDER`` (``geom = [R]``)
    The infinite circular cylinder ``y^2 + z^2 <= R^2`` with axis ``t = +x`` (a fiber
    along the warp direction). A surface point at azimuth ``psi`` (right-handed rotation
    about +x, ``psi = 0`` at the top) has outward normal ``n(psi) = (0, -sin psi, cos psi)``,
    local frame ``(n, t, b = n x t) = (n, x, (0, cos psi, sin psi))``. The distance to the
    boundary solves ``|p_perp + s u_perp|^2 = R^2`` for its positive root::

        a = u_y^2 + u_z^2,  b = p_y u_y + p_z u_z,  c = p_y^2 + p_z^2 - R^2 <= 0
        s = (-b + sqrt(b^2 - a c)) / a      (b <= 0)
        s = -c / (b + sqrt(b^2 - a c))      (b > 0, the same root without cancellation)

Both shapes are convex, so a free path from a point inside (or on the surface, heading
inwards) stays inside exactly when its END point is strictly inside (:func:`inside`):
the kernel tests ``p + l u`` against ``-d < z < 0`` or ``y^2 + z^2 < R^2`` -- no division
or square root -- and computes the distance to the boundary only for the (rarer) steps
that reach it.

Sources (``source = [mode, w_x, w_y, w_z]``, ``w`` the unit vector towards the light, so
photons travel along ``-w``):

* slab: entry at the origin of the top face;
* cylinder, ``mode = BEAM``: a parallel beam; the impact parameter ``b`` is uniform over the
  projected width ``[-R, R]`` along ``e = (x x d) / |x x d|`` and the entry point is the first
  intersection ``p = b e - sqrt(R^2 - b^2) / |d_perp| d`` (the direct beam estimator, sec. 5);
* cylinder, ``mode = POINT``: every photon enters at the cell A (``psi = 0, v = 0``), i.e. at
  ``(0, 0, R)``;
* cylinder, ``mode = CELL`` (``source[4] = h``, the half width of the cell A): the entry point
  is uniform over the cell, ``psi = (2 xi - 1) h`` at ``v = 0``, under the parallel beam ``w``
  (fixed in the fiber frame, so the local incidence varies across the cell as it does on a
  real fiber); the kernel gives each photon the launch weight ``max(w . n(psi), 0)``, the
  irradiance on the surface per unit beam irradiance (the BSSRDF route, sec. 4).

All functions are ``numba.njit(cache=True)`` helpers inlined into the kernel.
"""

from __future__ import annotations

import math

import numba

__all__ = [
    "core_length",
    "SLAB",
    "CYLINDER",
    "BEAM",
    "POINT",
    "CELL",
    "inside",
    "distance_to_boundary",
    "outward_normal",
    "snap_to_surface",
    "entry_point",
]

SLAB = 0
CYLINDER = 1
BEAM = 0
POINT = 1
CELL = 2


@numba.njit(cache=True, inline="always")
def core_length(y: float, z: float, uy: float, uz: float, s: float, a: float) -> float:
    """The length of a path segment that lies within the radius ``a`` of the axis.

    The segment starts at ``(y, z)`` (the cross-section's coordinates of a point of the cylinder) and runs
    along ``u`` for ``s`` (a unit direction: ``s`` is the path length); the length is from the roots of
    ``|p_perp + t u_perp|^2 = a^2`` clipped to ``[0, s]`` (a dye profile's inner boundary).
    A path along the axis is inside for its whole length or not at all.
    """
    if s <= 0.0:
        return 0.0
    q = uy * uy + uz * uz
    c = y * y + z * z - a * a
    if q < 1e-24:
        return s if c < 0.0 else 0.0
    b = y * uy + z * uz
    disc = b * b - q * c
    if disc <= 0.0:
        return 0.0
    root = math.sqrt(disc)
    lo = max((-b - root) / q, 0.0)
    hi = min((-b + root) / q, s)
    return hi - lo if hi > lo else 0.0


@numba.njit(cache=True, inline="always")
def inside(geometry: int, size: float, x: float, y: float, z: float) -> bool:
    """True if ``(x, y, z)`` is strictly inside the shape (False for NaN coordinates)."""
    if geometry == SLAB:
        return z < 0.0 and z > -size
    return y * y + z * z < size * size


@numba.njit(cache=True, inline="always")
def distance_to_boundary(
    geometry: int, size: float, x: float, y: float, z: float, ux: float, uy: float, uz: float
) -> float:
    """Distance from an inside point along ``u`` to the boundary (``inf`` if never reached)."""
    if geometry == SLAB:
        if uz > 0.0:
            return max(-z, 0.0) / uz
        if uz < 0.0:
            return min(-size - z, 0.0) / uz
        return math.inf
    a = uy * uy + uz * uz
    if a <= 0.0:
        return math.inf
    b = y * uy + z * uz
    c = min(y * y + z * z - size * size, 0.0)
    disc = math.sqrt(max(b * b - a * c, 0.0))
    if b <= 0.0:
        return (disc - b) / a
    return -c / (b + disc)


@numba.njit(cache=True, inline="always")
def outward_normal(
    geometry: int, size: float, x: float, y: float, z: float, uz: float
) -> tuple[float, float, float]:
    """Outward unit normal at a boundary point (slab: the face the direction ``uz`` reaches)."""
    if geometry == SLAB:
        if uz > 0.0:
            return 0.0, 0.0, 1.0
        return 0.0, 0.0, -1.0
    r = math.sqrt(y * y + z * z)
    return 0.0, y / r, z / r


@numba.njit(cache=True, inline="always")
def snap_to_surface(
    geometry: int, size: float, x: float, y: float, z: float, uz: float
) -> tuple[float, float, float]:
    """Put a point that reached the boundary exactly on it (stops rounding drift)."""
    if geometry == SLAB:
        if uz > 0.0:
            return x, y, 0.0
        return x, y, -size
    r = math.sqrt(y * y + z * z)
    f = size / r
    return x, y * f, z * f


@numba.njit(cache=True, inline="always")
def entry_point(
    geometry: int, size: float, mode: int, wx: float, wy: float, wz: float, half_width: float, xi: float
) -> tuple[float, float, float, float, float, float]:
    """Entry point and outward normal there for a photon travelling along ``-w``.

    Parameters
    ----------
    geometry : int
        ``SLAB`` or ``CYLINDER``.
    size : float
        ``d`` or ``R``.
    mode, wx, wy, wz, half_width
        The source (``source`` array unpacked): mode, ``w``, half width of the cell.
    xi : float
        Uniform random number in [0, 1) (impact parameter of the cylinder beam).

    Returns
    -------
    tuple
        ``(x, y, z, n_x, n_y, n_z)``.
    """
    if geometry == SLAB:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 1.0
    radius = size
    if mode == POINT:
        return 0.0, 0.0, radius, 0.0, 0.0, 1.0
    if mode == CELL:
        psi = (2.0 * xi - 1.0) * half_width
        sp = math.sin(psi)
        cp = math.cos(psi)
        return 0.0, -radius * sp, radius * cp, 0.0, -sp, cp
    dx = -wx
    dy = -wy
    dz = -wz
    q = math.sqrt(dy * dy + dz * dz)
    b = (2.0 * xi - 1.0) * radius
    s = -math.sqrt(max(radius * radius - b * b, 0.0)) / q
    x = s * dx
    y = -b * dz / q + s * dy
    z = b * dy / q + s * dz
    r = math.sqrt(y * y + z * z)
    ny = y / r
    nz = z / r
    return x, radius * ny, radius * nz, 0.0, ny, nz
