"""Light crossing a rough dielectric boundary inside the kernel (docs/physics.md section 3, "Rough boundary").

The fiber's surface term is Cook-Torrance with a Beckmann RMS slope ``m`` (section 5); until this
module the light that the kernel walks through the same surface crossed it as a smooth interface, so
a nearly clear fiber sent its exits onto sharp refraction cones that a rough fiber does not have.
With ``[surface] transmission_rms_slope = m_t > 0`` every crossing -- the entry, each internal
reflection and the exit -- happens at a microfacet of a Beckmann surface of RMS slope ``m_t``
(Walter, Marschner, Li & Torrance 2007, "Microfacet models for refraction through rough surfaces",
EGSR; the same model as Mitsuba's and pbrt's ``roughdielectric``):

* a microfacet normal ``h`` is drawn with density ``D(h) (h.n)`` (``n`` the macro normal on the side
  the light goes to), and the light is weighted by ``(u.h)+ G1(u) / ((u.n)(h.n))``: the share of a
  beam along ``u`` that meets facets of normal ``h``, over the sampling density (its integral over
  ``h`` is exactly 1 for Smith's ``G1``, so this weight is 1 on average);
* at the facet the light is reflected with the unpolarised Fresnel probability ``F(u.h)`` (total
  internal reflection included) or refracted by Snell about ``h``;
* the outgoing direction is masked by ``G1(o)`` (Smith's uncorrelated form, as Walter et al.), and
  a direction that would go to the wrong side of the macro surface is lost. The light lost to
  masking (a few per cent at ``m`` 0.25; the light that a real surface would scatter once more
  between its facets) is booked as absorbed by the kernel.

``G1`` is Smith's for the Beckmann distribution, ``1 / (1 + Lambda(a))`` with ``a = 1 / (m tan
theta)`` and ``Lambda(a) = (erf(a) - 1) / 2 + exp(-a^2) / (2 a sqrt(pi))`` (Walter et al. eq. 27).
At ``m_t = 0`` the kernel takes its smooth branch: a smooth boundary's results, bit for bit.
"""

from __future__ import annotations

import math

import numba

from simulate.optics.fresnel import fresnel_unpolarized, refracted_cos

_INV_SQRT_PI = 1.0 / math.sqrt(math.pi)


@numba.njit(cache=True, inline="always")
def smith_g1(cos_v: float, m: float) -> float:
    """Smith's masking ``G1`` of the Beckmann surface of RMS slope ``m``.

    For a direction at ``|cos_v|`` to the normal; ``m`` is the slope in the direction's own azimuth for an
    anisotropic surface (:func:`slope_towards`).
    """
    c = abs(cos_v)
    if c >= 1.0:
        return 1.0
    if c <= 0.0:
        return 0.0
    tan_t = math.sqrt(1.0 - c * c) / c
    if m * tan_t <= 0.0:
        return 1.0
    a = 1.0 / (m * tan_t)
    lam = 0.5 * (math.erf(a) - 1.0) + math.exp(-a * a) * _INV_SQRT_PI / (2.0 * a)
    return 1.0 / (1.0 + lam)


@numba.njit(cache=True, inline="always")
def slope_towards(vx: float, vy: float, vz: float, nx: float, ny: float, nz: float, m_a: float, m_b: float) -> float:
    """The RMS slope of the anisotropic Beckmann surface in the azimuth of ``v``.

    ``m_a`` is the slope along the fiber axis ``t = x``, ``m_b`` about it; the azimuth is that of ``v``'s
    projection on the tangent plane (Heitz 2014, section 5.3: ``alpha^2 = cos^2 phi m_a^2 + sin^2 phi m_b^2``).
    """
    if m_a == m_b:
        return m_a
    vn = vx * nx + vy * ny + vz * nz
    pt = vx - vn * nx          # the projection's component along t = (1, 0, 0) (t is in the tangent plane)
    p2 = max(1.0 - vn * vn, 0.0)
    if p2 <= 0.0:
        return m_a
    c2 = min(pt * pt / p2, 1.0)
    return math.sqrt(c2 * m_a * m_a + (1.0 - c2) * m_b * m_b)


@numba.njit(cache=True, inline="always")
def facet_normal(nx: float, ny: float, nz: float, m_a: float, m_b: float, u1: float, u2: float):
    """A Beckmann microfacet normal about the unit ``n`` with density ``D(h)(h.n)``.

    Slopes are drawn from the Beckmann slope distribution, RMS slope ``m_a`` along the fiber axis
    ``t = (1, 0, 0)`` (which lies in every tangent plane of the kernel's cylinder and slab) and ``m_b``
    along ``b = n x t``; returns ``h`` and ``h.n``.
    """
    r = math.sqrt(-math.log(1.0 - u1))
    phi = 2.0 * math.pi * u2
    s_t = m_a * r * math.cos(phi)
    s_b = m_b * r * math.sin(phi)
    # t = (1, 0, 0); b = n x t = (0, nz, -ny)
    hx = nx - s_t
    hy = ny - s_b * nz
    hz = nz + s_b * ny
    norm = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    return hx * norm, hy * norm, hz * norm, norm * (nx * nx + ny * ny + nz * nz)


@numba.njit(cache=True, inline="always")
def refract_about(ux: float, uy: float, uz: float, hx: float, hy: float, hz: float, cos_i: float, n1: float,
                  n2: float):
    """Snell's refraction of the unit ``u`` about the unit normal ``h``.

    ``cos_i = u.h > 0``, below total internal reflection; ``h`` points to the side of index ``n2``. The
    refracted direction is ``eta u + (cos_t - eta cos_i) h``, ``eta = n1/n2``.
    """
    eta = n1 / n2
    k = refracted_cos(cos_i, n1, n2) - eta * cos_i
    ox = eta * ux + k * hx
    oy = eta * uy + k * hy
    oz = eta * uz + k * hz
    norm = 1.0 / math.sqrt(ox * ox + oy * oy + oz * oz)
    return ox * norm, oy * norm, oz * norm


@numba.njit(cache=True, inline="always")
def rough_cross(ux: float, uy: float, uz: float, nx: float, ny: float, nz: float, n1: float, n2: float,
                m_a: float, m_b: float, u1: float, u2: float, u3: float):
    """Light along ``u`` meets a rough boundary from the side of index ``n1``.

    ``n`` is the unit macro normal pointing to the side of index ``n2`` (``u.n > 0``).
    One microfacet is drawn (``u1``, ``u2``), then reflection or refraction at it (``u3`` against its
    Fresnel reflectance). Returns ``(ox, oy, oz, factor, crossed)``: the new direction, the weight
    factor (0: the light is lost -- a back-facing facet or a masked or wrong-side direction), and
    whether it went through to the ``n2`` side.
    """
    cos_un = ux * nx + uy * ny + uz * nz
    hx, hy, hz, cos_hn = facet_normal(nx, ny, nz, m_a, m_b, u1, u2)
    uh = ux * hx + uy * hy + uz * hz
    if uh <= 0.0 or cos_un <= 0.0:
        return ux, uy, uz, 0.0, False
    omega = uh * smith_g1(cos_un, slope_towards(ux, uy, uz, nx, ny, nz, m_a, m_b)) / (cos_un * cos_hn)
    f = fresnel_unpolarized(uh, n1, n2)
    if u3 < f:
        ox = ux - 2.0 * uh * hx
        oy = uy - 2.0 * uh * hy
        oz = uz - 2.0 * uh * hz
        on = ox * nx + oy * ny + oz * nz
        if on >= 0.0:
            return ox, oy, oz, 0.0, False
        return ox, oy, oz, omega * smith_g1(on, slope_towards(ox, oy, oz, nx, ny, nz, m_a, m_b)), False
    ox, oy, oz = refract_about(ux, uy, uz, hx, hy, hz, uh, n1, n2)
    on = ox * nx + oy * ny + oz * nz
    if on <= 0.0:
        return ox, oy, oz, 0.0, True
    return ox, oy, oz, omega * smith_g1(on, slope_towards(ox, oy, oz, nx, ny, nz, m_a, m_b)), True


@numba.njit(cache=True, inline="always")
def rough_entry(dx: float, dy: float, dz: float, nx: float, ny: float, nz: float, n_in: float, m_a: float,
                m_b: float, u1: float, u2: float):
    """Light from outside along ``d`` enters through a rough boundary of outward normal ``n``.

    Both outcomes at the drawn facet are kept, as the smooth entry keeps them: returns ``(ux, uy, uz,
    transmitted, reflected)``, the refracted direction inside and the weights (per unit arriving) that
    go in along it and that the facet reflects out (the specular part, counted only).
    """
    cos_dn = -(dx * nx + dy * ny + dz * nz)
    hx, hy, hz, cos_hn = facet_normal(-nx, -ny, -nz, m_a, m_b, u1, u2)
    dh = dx * hx + dy * hy + dz * hz
    if dh <= 0.0 or cos_dn <= 0.0:
        return dx, dy, dz, 0.0, 0.0
    omega = dh * smith_g1(cos_dn, slope_towards(dx, dy, dz, nx, ny, nz, m_a, m_b)) / (cos_dn * cos_hn)
    f = fresnel_unpolarized(dh, 1.0, n_in)
    # the reflected part (out of the medium) and its masking
    rx = dx - 2.0 * dh * hx
    ry = dy - 2.0 * dh * hy
    rz = dz - 2.0 * dh * hz
    rn = rx * nx + ry * ny + rz * nz
    reflected = omega * f * smith_g1(rn, slope_towards(rx, ry, rz, nx, ny, nz, m_a, m_b)) if rn > 0.0 else 0.0
    ux, uy, uz = refract_about(dx, dy, dz, hx, hy, hz, dh, 1.0, n_in)
    un = -(ux * nx + uy * ny + uz * nz)
    if un <= 0.0:
        return ux, uy, uz, 0.0, reflected
    return ux, uy, uz, omega * (1.0 - f) * smith_g1(un, slope_towards(ux, uy, uz, nx, ny, nz, m_a, m_b)), reflected
