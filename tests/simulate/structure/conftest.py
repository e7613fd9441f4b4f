"""An independent brute-force photon tracer of a fiber (alone or in a layer of touching fibers).

It shares no code with the project's kernel: photons of a parallel beam hit an infinite cylinder
(axis x, radius R), are refracted with the unpolarised Fresnel split (the reflected part is the
surface term, not traced: only the volume is compared), walk the Henyey-Greenstein medium with
analog absorption, are reflected or refracted at the wall with probability F, and are tallied by
exit direction.

``layer_d = 0``: an isolated fiber; photons enter uniformly over the projected width ``2R``; bins
of ``(w_x, atan2(w_y, w_z))`` over the sphere (equal solid angles); each photon stands for
``E_perp 2 R |w_perp| / N`` per unit length.

``layer_d > 0``: the fiber in a layer of parallel fibers at ``y = j d`` (``d >= 2R``); photons start
on the plane ``z = 3R`` uniformly over one period along y and hit the first cylinder in their way
(the periodic layer maps it onto the central one); an exit ray that meets a neighbour is masked
(dropped), one leaving downwards is dropped; bins of ``(w_z, atan2(w_y, w_x))`` over the upper
hemisphere (equal solid angles); each photon stands for ``E_perp w_z d / N`` per unit length.
``down = True`` (layer only): the other way round -- the exits leaving DOWNWARDS past the neighbours are
tallied, in bins of ``(-w_z, atan2(w_y, w_x))`` over the lower hemisphere, the upward ones dropped.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest


@numba.njit(cache=True)
def _fresnel(cos_i, n1, n2):
    s = n1 / n2 * math.sqrt(max(0.0, 1.0 - cos_i * cos_i))
    if s >= 1.0:
        return 1.0, 0.0
    cos_t = math.sqrt(1.0 - s * s)
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n1 * cos_t - n2 * cos_i) / (n1 * cos_t + n2 * cos_i)
    return 0.5 * (rs * rs + rp * rp), cos_t


@numba.njit(cache=True)
def _hg(u, v, w, g, r1, r2):
    if abs(g) < 1e-6:
        ct = 2.0 * r1 - 1.0
    else:
        q = (1.0 - g * g) / (1.0 - g + 2.0 * g * r1)
        ct = (1.0 + g * g - q * q) / (2.0 * g)
    ct = min(1.0, max(-1.0, ct))
    st = math.sqrt(1.0 - ct * ct)
    ph = 2.0 * math.pi * r2
    if abs(w) < 0.9:
        ax, ay, az = -v, u, 0.0
    else:
        ax, ay, az = 0.0, -w, v
    na = math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / na, ay / na, az / na
    bx, by, bz = v * az - w * ay, w * ax - u * az, u * ay - v * ax
    return (ct * u + st * (math.cos(ph) * ax + math.sin(ph) * bx),
            ct * v + st * (math.cos(ph) * ay + math.sin(ph) * by),
            ct * w + st * (math.cos(ph) * az + math.sin(ph) * bz))


@numba.njit(cache=True)
def _hits_circle(py, pz, uy, uz, cy, radius):
    """Does the 2-D ray p + s u (s > 0, u not normalised) meet the circle at (cy, 0)?"""
    qy, qz = py - cy, pz
    a = uy * uy + uz * uz
    if a == 0.0:
        return False
    b = (qy * uy + qz * uz) / a
    c = (qy * qy + qz * qz - radius * radius) / a
    disc = b * b - c
    return disc > 0.0 and -b - math.sqrt(disc) > 1e-9 * radius


@numba.njit(cache=True)
def trace(n_photons, seed, wx, wy, wz, radius, n, mu_s, mu_a, g, layer_d, n_1, n_2, down=False):
    np.random.seed(seed)
    sums = np.zeros((n_1, n_2))
    sq = np.zeros((n_1, n_2))
    dx, dy, dz = -wx, -wy, -wz                       # travel direction
    dp = math.sqrt(dy * dy + dz * dz)
    ey, ez = -dz / dp, dy / dp                        # across the projected width
    mu_t = mu_s + mu_a
    for _ in range(n_photons):
        if layer_d == 0.0:
            b = (2.0 * np.random.random() - 1.0) * radius
            h = math.sqrt(radius * radius - b * b)
            py, pz = b * ey - h * dy / dp, b * ez - h * dz / dp
        else:
            # start on z = 3R over one period; the first cylinder j the ray meets
            oy, oz = np.random.random() * layer_d, 3.0 * radius
            best, by_, bz_ = 1e300, 0.0, 0.0
            for j in range(-40, 41):
                cy = j * layer_d
                qy, qz = oy - cy, oz
                bb = qy * dy + qz * dz
                cc = qy * qy + qz * qz - radius * radius
                aa = dy * dy + dz * dz
                disc = bb * bb - aa * cc
                if disc <= 0.0:
                    continue
                s = (-bb - math.sqrt(disc)) / aa
                if 0.0 < s < best:
                    best, by_, bz_ = s, oy + s * dy - cy, oz + s * dz
            if best == 1e300:
                continue
            py, pz = by_, bz_
        px = 0.0
        ny, nz = py / radius, pz / radius
        cos_i = -(dy * ny + dz * nz)
        f, cos_t = _fresnel(cos_i, 1.0, n)
        weight = 1.0 - f
        eta = 1.0 / n
        ux = eta * dx
        uy = eta * dy + (eta * cos_i - cos_t) * ny
        uz = eta * dz + (eta * cos_i - cos_t) * nz
        while True:
            s = -math.log(1.0 - np.random.random()) / mu_t
            a = uy * uy + uz * uz
            bb = py * uy + pz * uz
            c = py * py + pz * pz - radius * radius
            sb = (-bb + math.sqrt(max(bb * bb - a * c, 0.0))) / a if a > 0 else 1e300
            if s < sb:
                px, py, pz = px + s * ux, py + s * uy, pz + s * uz
                if np.random.random() > mu_s / mu_t:
                    break                              # absorbed (analog)
                ux, uy, uz = _hg(ux, uy, uz, g, np.random.random(), np.random.random())
                continue
            px, py, pz = px + sb * ux, py + sb * uy, pz + sb * uz
            rr = math.sqrt(py * py + pz * pz)
            ny, nz = py / rr, pz / rr
            py, pz = ny * radius, nz * radius
            cos_in = uy * ny + uz * nz
            f, cos_out = _fresnel(cos_in, n, 1.0)
            if np.random.random() < f:                 # internal reflection
                uy, uz = uy - 2.0 * cos_in * ny, uz - 2.0 * cos_in * nz
                continue
            ox = n * ux
            oy = n * uy + (cos_out - n * cos_in) * ny
            oz = n * uz + (cos_out - n * cos_in) * nz
            no = math.sqrt(ox * ox + oy * oy + oz * oz)
            ox, oy, oz = ox / no, oy / no, oz / no
            if layer_d == 0.0:
                i1 = min(int((ox + 1.0) * 0.5 * n_1), n_1 - 1)
                i2 = min(int((math.atan2(oy, oz) + math.pi) / (2.0 * math.pi) * n_2), n_2 - 1)
            else:
                if (oz >= 0.0 if down else oz <= 0.0) or _hits_circle(py, pz, oy, oz, layer_d, radius) or \
                        _hits_circle(py, pz, oy, oz, -layer_d, radius):
                    break                              # masked, or leaving on the side not tallied
                i1 = min(int(abs(oz) * n_1), n_1 - 1)
                i2 = min(int((math.atan2(oy, ox) + math.pi) / (2.0 * math.pi) * n_2), n_2 - 1)
            sums[i1, i2] += weight
            sq[i1, i2] += weight * weight
            break
    return sums, sq


@pytest.fixture(scope="session")
def tracer():
    """The brute-force tracer (module docstring): ``trace(n, seed, *w_in, R, n, mu_s, mu_a, g, layer_d, n_1, n_2)``."""
    return trace
