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
At ``m_t = 0`` the kernel takes its smooth branch, bit for bit the previous code.
"""

from __future__ import annotations

import math

import numba

from simulate.optics.fresnel import fresnel_unpolarized, refracted_cos

_INV_SQRT_PI = 1.0 / math.sqrt(math.pi)


@numba.njit(cache=True, inline="always")
def smith_g1(cos_v: float, m: float) -> float:
    """Smith's masking ``G1`` of the Beckmann surface of RMS slope ``m`` for a direction at ``|cos_v|`` to the normal."""
    c = abs(cos_v)
    if c >= 1.0:
        return 1.0
    if c <= 0.0:
        return 0.0
    tan_t = math.sqrt(1.0 - c * c) / c
    a = 1.0 / (m * tan_t)
    lam = 0.5 * (math.erf(a) - 1.0) + math.exp(-a * a) * _INV_SQRT_PI / (2.0 * a)
    return 1.0 / (1.0 + lam)


@numba.njit(cache=True, inline="always")
def facet_normal(nx: float, ny: float, nz: float, m: float, u1: float, u2: float):
    """A Beckmann microfacet normal about the unit ``n``, density ``D(h)(h.n)``; returns ``h`` and ``h.n``."""
    tan2 = -(m * m) * math.log(1.0 - u1)
    cos_h = 1.0 / math.sqrt(1.0 + tan2)
    sin_h = math.sqrt(max(0.0, 1.0 - cos_h * cos_h))
    phi = 2.0 * math.pi * u2
    # orthonormal basis about n (Duff et al. 2017)
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    t1x = 1.0 + sign * nx * nx * a
    t1y = sign * b
    t1z = -sign * nx
    t2x = b
    t2y = sign + ny * ny * a
    t2z = -ny
    cp = math.cos(phi) * sin_h
    sp = math.sin(phi) * sin_h
    hx = cp * t1x + sp * t2x + cos_h * nx
    hy = cp * t1y + sp * t2y + cos_h * ny
    hz = cp * t1z + sp * t2z + cos_h * nz
    norm = 1.0 / math.sqrt(hx * hx + hy * hy + hz * hz)
    return hx * norm, hy * norm, hz * norm, cos_h


@numba.njit(cache=True, inline="always")
def rough_cross(ux: float, uy: float, uz: float, nx: float, ny: float, nz: float, n1: float, n2: float,
                m: float, u1: float, u2: float, u3: float):
    """Light along ``u`` meets a rough boundary from the side of index ``n1``; ``n`` the unit macro
    normal pointing to the side of index ``n2`` (``u.n > 0``).

    One microfacet is drawn (``u1``, ``u2``), then reflection or refraction at it (``u3`` against its
    Fresnel reflectance). Returns ``(ox, oy, oz, factor, crossed)``: the new direction, the weight
    factor (0: the light is lost -- a back-facing facet or a masked or wrong-side direction), and
    whether it went through to the ``n2`` side.
    """
    cos_un = ux * nx + uy * ny + uz * nz
    hx, hy, hz, cos_hn = facet_normal(nx, ny, nz, m, u1, u2)
    uh = ux * hx + uy * hy + uz * hz
    if uh <= 0.0 or cos_un <= 0.0:
        return ux, uy, uz, 0.0, False
    omega = uh * smith_g1(cos_un, m) / (cos_un * cos_hn)
    f = fresnel_unpolarized(uh, n1, n2)
    if u3 < f:
        ox = ux - 2.0 * uh * hx
        oy = uy - 2.0 * uh * hy
        oz = uz - 2.0 * uh * hz
        on = ox * nx + oy * ny + oz * nz
        if on >= 0.0:
            return ox, oy, oz, 0.0, False
        return ox, oy, oz, omega * smith_g1(on, m), False
    eta = n1 / n2
    cos_t = refracted_cos(uh, n1, n2)
    k = cos_t - eta * uh
    ox = eta * ux + k * hx
    oy = eta * uy + k * hy
    oz = eta * uz + k * hz
    norm = 1.0 / math.sqrt(ox * ox + oy * oy + oz * oz)
    ox *= norm
    oy *= norm
    oz *= norm
    on = ox * nx + oy * ny + oz * nz
    if on <= 0.0:
        return ox, oy, oz, 0.0, True
    return ox, oy, oz, omega * smith_g1(on, m), True


@numba.njit(cache=True, inline="always")
def rough_entry(dx: float, dy: float, dz: float, nx: float, ny: float, nz: float, n_in: float, m: float,
                u1: float, u2: float):
    """Light from outside along ``d`` enters through a rough boundary of outward normal ``n``.

    Both outcomes at the drawn facet are kept, as the smooth entry keeps them: returns ``(ux, uy, uz,
    transmitted, reflected)``, the refracted direction inside and the weights (per unit arriving) that
    go in along it and that the facet reflects out (the specular part, counted only).
    """
    cos_dn = -(dx * nx + dy * ny + dz * nz)
    hx, hy, hz, cos_hn = facet_normal(-nx, -ny, -nz, m, u1, u2)
    dh = dx * hx + dy * hy + dz * hz
    if dh <= 0.0 or cos_dn <= 0.0:
        return dx, dy, dz, 0.0, 0.0
    omega = dh * smith_g1(cos_dn, m) / (cos_dn * cos_hn)
    f = fresnel_unpolarized(dh, 1.0, n_in)
    # the reflected part (out of the medium) and its masking
    rx = dx - 2.0 * dh * hx
    ry = dy - 2.0 * dh * hy
    rz = dz - 2.0 * dh * hz
    rn = rx * nx + ry * ny + rz * nz
    reflected = omega * f * smith_g1(rn, m) if rn > 0.0 else 0.0
    eta = 1.0 / n_in
    cos_t = refracted_cos(dh, 1.0, n_in)
    k = cos_t - eta * dh
    ux = eta * dx + k * hx
    uy = eta * dy + k * hy
    uz = eta * dz + k * hz
    norm = 1.0 / math.sqrt(ux * ux + uy * uy + uz * uz)
    ux *= norm
    uy *= norm
    uz *= norm
    un = -(ux * nx + uy * ny + uz * nz)
    if un <= 0.0:
        return ux, uy, uz, 0.0, reflected
    return ux, uy, uz, omega * (1.0 - f) * smith_g1(un, m), reflected
