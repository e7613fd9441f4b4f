r"""A nonwoven felt for the woven-fabric tracer: a random layer of straight fibers in a periodic cell.

The summation's felt (:func:`simulate.fabric.structure.felt_facets`, docs/physics.md 6.2) has fibers
whose in-plane direction is uniform in ``[0, 180)`` deg and whose inclination ``epsilon`` out of the
plane is normal with standard deviation ``felt_spread_deg`` (truncated at +-80 deg). Here the same
fibers are built as geometry and traced on Embree like the weave's yarns:

* **Cell**: ``[0, L) x [0, L)`` with ``L = 40 R`` (``R`` the fiber radius), periodic as the weave's
  micro-element (:mod:`simulate.woven.scene`).
* **Fibers**: straight circular tubes of radius ``R``, length ``l = 40 R``, each with a uniform
  random in-plane position and a direction drawn from the distribution above. A fiber that crosses
  the cell's sides is also put in at its periodic images (shifted by ``+-L``), so the cell tiles the
  plane seamlessly.
* **Needle-punched fibers** (``felt_normal_fraction``, ``felt_normal_spread_deg``): needle punching drives
  part of the web's fibers from the plane towards the normal; X-ray CT of needle-punched nonwovens finds
  fibers parallel and perpendicular to the normal and few in between (Text. Res. J., doi
  10.1177/0040517517736470). With probability ``felt_normal_fraction`` a fiber is drawn from that
  second population: tilted from the normal by ``|N(0, felt_normal_spread_deg)|`` (truncated at 80 deg)
  towards a uniform azimuth, counted by its material (``2 R l``, as a fiber lying flat) in the amount
  below. It is deposited like the others (on the floor or on the fibers below), so it stands among
  them and may stand out of the top. The fraction 0 (the default) draws nothing more from the stream:
  the felt is bit for bit the in-plane one. The summation's felt (6.2) has no such population (a
  warning says so).
* **How many**: the summation's felt is ``layers`` (``structure.layers``, default 10) layers of
  parallel fibers at spacing ``d = 2 R spacing_ratio`` (the packing fraction's); here the fibers'
  projected area ``2 R l cos(epsilon)`` adds up to the same ``layers L^2 / spacing_ratio`` (the same
  amount of fiber per unit area).
* **No two fibers interpenetrate**. Fibers placed independently overlap where they cross
  (at the layers' density a covered point lay in 1.47 fibers on average), and a tracer that walks
  each fiber's volume from a table walks the shared material once per fiber: with absorbing fibers
  the felt was 16 % too dark (docs/physics.md 6). Treating the union instead would need the walk in
  the union of cylinders, which the per-fiber exit tables cannot give, so the geometry is made
  physical: the fibers are deposited one by one, each put at the *lowest height* at which it lies on
  the floor or in a gap of the fibers below without touching any (random sequential deposition with
  settling into the lowest gap, the way a web is laid; :func:`_lowest_free_height`: the axes kept
  ``2 R`` apart -- a spherocylinder test, slightly conservative at the fibers' ends). The felt's top
  is put at ``z = 0``.
* **Volume fraction**: rigid straight fibers of aspect ratio 20 jam loosely: this deposition reaches
  a bulk volume fraction of about 0.11 (spread 20 deg) to 0.16 (spread 0, fibers in the plane)
  (``info["volume_fraction"]``, measured between the quartiles of the centres' heights). Random
  sequential addition with rejection in a slab reaches no more (it jammed at 0.14-0.19, the fibers'
  volume over their centres' slab, 20 000 tries a fiber), and picking the lowest of 4-16 positions
  per fiber gave only 0.13-0.15 for 4-16 times the cost (measured).
  The summation's layers of touching fibers (packing 0.9069) are beyond any random straight-fiber
  layer: the felt keeps the layers' *fiber amount* and the orientation distribution and takes the
  thickness the deposition gives (10 touching layers of 20-um fibers: ~1.2-1.8 mm instead of 0.2 mm).
  A requested packing below the deposition's density (< ~0.11) is not loosened further (it only sets
  the fiber count): compare with the summation at the felt's measured volume fraction
  (the felt study, :func:`fabric_optics.bench.felt.run_felt_study` with ``packing_fraction``).
* **Ends**: the tubes are open. An end is ``R / l = 2.5 %`` of a fiber's surface; light that enters
  one meets the tube's inside and is taken into the fiber's volume (the interpenetration rule).
* **Mesh**: the weave mesh's contract (:mod:`simulate.fabric.weave`): one "yarn" per fiber image,
  ``(n_s + 1) x (sides + 1)`` vertices, ``s`` the arc length along the fiber (``open_fibers``: the
  tracer clamps exits to the tube's ends instead of wrapping them round a periodic yarn, and puts
  rays that leave from an image outside the cell back into it), vertex normals radial; no twist.

The yarn table is the fiber's own (``r_yarn = R``: the exit offsets need no scaling).

Limits: straight fibers (a real felt's fibers are crimped, curl and pack denser), a floor under the first fibers
(the felt's bottom is flat; with 10 layers' fiber little light reaches it), a cell of 40 R (about
20 fibers across): one realisation varies from the next by ~2 % of each direction's peak (green felt),
which ``simulate fabric --method mc`` puts into ``u_beta`` by tracing each of its two table halves on
its own realisation, at several azimuths (:mod:`simulate.woven.estimate`, "A felt").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["FeltMesh", "felt_mesh", "CELL_RADII", "LENGTH_RADII"]

#: the cell's side and the fibers' length, in fiber radii
CELL_RADII = 40.0
LENGTH_RADII = 40.0
#: two fibers' axes are kept at least this many diameters apart (a margin for rounding; the mesh's
#: polygonal tubes are inscribed in the cylinders)
CONTACT = 1.0 + 1e-6


@dataclass
class FeltMesh:
    """The felt's fibers in the weave mesh's contract (module docstring), plus ``info``."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    vertex_s: np.ndarray
    vertex_phi: np.ndarray
    vertex_yarn: np.ndarray
    face_yarn: np.ndarray
    vertex_base: np.ndarray
    face_base: np.ndarray
    n_s: np.ndarray
    yarn_length: np.ndarray
    sides: int
    Lx: float
    Ly: float
    z_min: float
    z_max: float
    yarn_radius_um: float
    open_fibers: bool = True
    info: dict = field(default_factory=dict)


def _tube(c: np.ndarray, t: np.ndarray, radius: float, length: float, n_s: int, sides: int):
    """Vertices, normals, s and phi of one straight tube (centre ``c``, unit direction ``t``)."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(t[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(helper, t)
    u /= np.linalg.norm(u)
    v = np.cross(t, u)                       # (u, v, t) right-handed: dP/dphi x dP/ds points out
    s = np.linspace(0.0, length, n_s + 1)
    phi = 2.0 * math.pi * np.arange(sides + 1) / sides
    cos, sin = np.cos(phi), np.sin(phi)
    cos[-1], sin[-1] = cos[0], sin[0]
    S, C = np.meshgrid(s, cos, indexing="ij")
    _, Sn = np.meshgrid(s, sin, indexing="ij")
    nrm = C[..., None] * u + Sn[..., None] * v
    pts = c + (S[..., None] - 0.5 * length) * t + radius * nrm
    PHI = np.broadcast_to(phi[None, :], S.shape)
    return pts.reshape(-1, 3), nrm.reshape(-1, 3), S.reshape(-1), PHI.reshape(-1)


def _segment_distance(p1: np.ndarray, d1: np.ndarray, p2: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """Closest distance between the segments ``p1 + s d1`` and ``p2 + t d2``, ``s, t`` in ``[0, 1]``
    (rows broadcast; no degenerate segment). The clamped closest-point solution of Ericson (2005),
    *Real-Time Collision Detection*, section 5.1.9, vectorised."""
    r = p1 - p2
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    b = np.einsum("...i,...i->...", d1, d2)
    c = np.einsum("...i,...i->...", d1, r)
    f = np.einsum("...i,...i->...", d2, r)
    den = a * e - b * b
    skew = den > 1e-12 * a * e                 # not parallel
    s = np.where(skew, np.clip((b * f - c * e) / np.where(skew, den, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e
    s = np.where(t < 0.0, np.clip(-c / a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    d = r + s[..., None] * d1 - t[..., None] * d2
    return np.sqrt(np.einsum("...i,...i->...", d, d))


def _lowest_free_height(xy: np.ndarray, t: np.ndarray, C: np.ndarray, T: np.ndarray, R: float, ell: float,
                        L: float, iters: int = 36) -> float:
    """The lowest centre height at which a fiber of direction ``t`` over ``xy`` lies on the floor or in a
    gap of the fibers placed so far (centres ``C``, directions ``T``, periodic with period ``L``) without
    overlapping any of them (module docstring: contact distance ``CONTACT x 2R`` between the axes).

    For each fiber it can meet (its axis within ``2R`` of the candidate's in the plane: a necessary
    condition), the distance between the two axes as the candidate is moved vertically by ``w`` is
    convex in ``w`` (the distance between a translated convex set and a fixed one), so the heights at
    which they overlap are one interval: its minimum by golden section, its ends by bisection. The
    candidate goes at the lowest height above the floor outside every interval."""
    z = 0.5 * ell * abs(t[2]) + R               # resting on the floor z = 0
    if len(C) == 0:
        return z
    contact = 2.0 * R * CONTACT
    shifts = np.array([[i * L, j * L] for i in (-1, 0, 1) for j in (-1, 0, 1)])
    dxy = xy[None, :] - C[:, :2]
    dxy -= L * np.round(dxy / L)               # the nearest image, then its neighbours
    q = np.zeros((len(C) * 9, 3))
    q[:, :2] = (dxy[:, None, :] + shifts[None]).reshape(-1, 2)
    Tj, zj = np.repeat(T, 9, axis=0), np.repeat(C[:, 2], 9)
    t2, Tj2 = t * [1.0, 1.0, 0.0], Tj * [1.0, 1.0, 0.0]
    near = _segment_distance(q - 0.5 * ell * t2, ell * t2, -0.5 * ell * Tj2, ell * Tj2) < contact
    if not near.any():
        return z
    q, Tj, zj = q[near], Tj[near], zj[near]

    def gap(w: np.ndarray) -> np.ndarray:      # axis distance, candidate's centre w above fiber j's
        qq = q.copy()
        qq[:, 2] = w
        return _segment_distance(qq - 0.5 * ell * t, np.broadcast_to(ell * t, qq.shape), -0.5 * ell * Tj, ell * Tj)

    span = 0.5 * ell * (abs(t[2]) + np.abs(Tj[:, 2])) + contact + 1.0
    a, b = -span, span.copy()
    golden = 0.5 * (math.sqrt(5.0) - 1.0)
    for _ in range(iters):
        c1, c2 = b - golden * (b - a), a + golden * (b - a)
        left = gap(c1) < gap(c2)
        a, b = np.where(left, a, c1), np.where(left, c2, b)
    w_min = 0.5 * (a + b)
    hit = gap(w_min) < contact
    if not hit.any():
        return z
    q, Tj, zj, w_min, span = q[hit], Tj[hit], zj[hit], w_min[hit], span[hit]
    top_in, top_out = w_min.copy(), span.copy()          # the interval's upper end
    bot_out, bot_in = -span, w_min.copy()                 # and its lower end
    for _ in range(iters):
        mid = 0.5 * (top_in + top_out)
        inside = gap(mid) < contact
        top_in, top_out = np.where(inside, mid, top_in), np.where(inside, top_out, mid)
        mid = 0.5 * (bot_out + bot_in)
        inside = gap(mid) < contact
        bot_out, bot_in = np.where(inside, bot_out, mid), np.where(inside, mid, bot_in)
    lo, hi = zj + bot_out, zj + top_out                   # both ends on the free side
    for s0, e0 in zip(*(v[np.argsort(lo)] for v in (lo, hi))):
        if s0 >= z:
            break
        z = max(z, float(e0))
    return z


def felt_mesh(spec: object, radius_um: float, seed: int = 0, *, sides: int = 48, n_s: int = 4) -> FeltMesh:
    """The felt of ``spec`` (:class:`simulate.fabric.structure.StructureSpec`, ``kind = "nonwoven"``) for
    fibers of radius ``radius_um``: random fibers from the stream ``seed`` (module docstring)."""
    from simulate.fabric.mesh import grid_faces

    R = float(radius_um)
    L = CELL_RADII * R
    ell = LENGTH_RADII * R
    layers = int(getattr(spec, "layers", 0)) or 10
    ratio = float(getattr(spec, "spacing_ratio", 1.0))
    spread = math.radians(float(getattr(spec, "felt_spread_deg", 20.0)))
    punched = float(getattr(spec, "felt_normal_fraction", 0.0))
    tilt_sd = math.radians(float(getattr(spec, "felt_normal_spread_deg", 15.0)))
    rng = np.random.default_rng([int(seed), 0x7E17])
    target = layers * L * L / ratio           # the layers' projected fiber area
    area = 0.0
    n_normal = 0
    C, T = np.zeros((0, 3)), np.zeros((0, 3))
    while area < target:
        az = rng.uniform(0.0, math.pi)
        # a needle-punched fiber (drawn only when the fraction is set: today's felt keeps its stream)
        if punched > 0.0 and rng.uniform() < punched:
            az *= 2.0                          # the tilt's azimuth over the full circle
            tilt = abs(rng.normal(0.0, tilt_sd)) if tilt_sd > 0 else 0.0
            while tilt > math.radians(80.0):
                tilt = abs(rng.normal(0.0, tilt_sd))
            eps = 0.5 * math.pi - tilt
            amount = 2.0 * R * ell             # its material, counted as a fiber lying flat
            n_normal += 1
        else:
            eps = rng.normal(0.0, spread) if spread > 0 else 0.0
            while abs(eps) > math.radians(80.0):
                eps = rng.normal(0.0, spread)
            amount = 2.0 * R * ell * math.cos(eps)
        t = np.array([math.cos(eps) * math.cos(az), math.cos(eps) * math.sin(az), math.sin(eps)])
        xy = np.array([rng.uniform(0.0, L), rng.uniform(0.0, L)])
        z = _lowest_free_height(xy, t, C, T, R, ell, L)
        C, T = np.vstack([C, [xy[0], xy[1], z]]), np.vstack([T, t])
        area += amount
    top = float(np.max(C[:, 2] + 0.5 * ell * np.abs(T[:, 2]) + R))
    C[:, 2] -= top                             # the felt's top at z = 0
    verts, norms, tans, ss, phis, yarn_len = [], [], [], [], [], []
    for c, t in zip(C, T):
        half = 0.5 * ell * np.abs(t[:2]) + R
        for i in (-1, 0, 1):
            for j in (-1, 0, 1):
                cc = c + np.array([i * L, j * L, 0.0])
                if np.any(cc[:2] + half < 0.0) or np.any(cc[:2] - half > L):
                    continue                   # this image does not reach into the cell
                p, nrm, s, phi = _tube(cc, t, R, ell, n_s, sides)
                verts.append(p)
                norms.append(nrm)
                tans.append(np.broadcast_to(t, p.shape))
                ss.append(s)
                phis.append(phi)
                yarn_len.append(ell)
    n_y = len(verts)
    ring = (n_s + 1) * (sides + 1)
    vertex_base = (np.arange(n_y) * ring).astype(np.int64)
    face_base = (np.arange(n_y) * 2 * n_s * sides).astype(np.int64)
    faces = np.concatenate([grid_faces(n_s, sides, int(vertex_base[y])) for y in range(n_y)]).astype(np.int32)
    vertices = np.concatenate(verts)
    return FeltMesh(
        vertices=vertices, faces=faces, normals=np.concatenate(norms), tangents=np.ascontiguousarray(np.concatenate(tans)),
        vertex_s=np.concatenate(ss), vertex_phi=np.concatenate(phis),
        vertex_yarn=np.repeat(np.arange(n_y, dtype=np.int32), ring),
        face_yarn=np.repeat(np.arange(n_y, dtype=np.int32), 2 * n_s * sides),
        vertex_base=vertex_base, face_base=face_base, n_s=np.full(n_y, n_s, dtype=np.int32),
        yarn_length=np.array(yarn_len, float), sides=int(sides), Lx=L, Ly=L,
        z_min=float(vertices[:, 2].min()), z_max=float(vertices[:, 2].max()), yarn_radius_um=R,
        info={"fibers": len(C), "images": n_y, "cell_um": L, "fiber_length_um": ell, "thickness_um": top,
              "layers": layers, "spread_deg": math.degrees(spread),
              "normal_fibers": n_normal, "triangles": int(faces.shape[0]),
              "volume_fraction": bulk_volume_fraction(C, T, R, ell, L), "seed": int(seed)})


def bulk_volume_fraction(C: np.ndarray, T: np.ndarray, R: float, ell: float, L: float, n: int = 4000) -> float:
    """The fraction of the felt's bulk (the cell between the quartiles of the fibers' centre heights)
    inside a fiber: ``n`` fixed-seed random points (standard error ~ ``sqrt(f (1 - f) / n)``, 0.005)."""
    rng = np.random.default_rng(0xF17)
    z_lo, z_hi = np.quantile(C[:, 2], [0.25, 0.75])
    p = np.stack([rng.uniform(0.0, L, n), rng.uniform(0.0, L, n), rng.uniform(z_lo, z_hi, n)], axis=-1)
    inside = np.zeros(n, bool)
    for c, t in zip(C, T):
        d = p - c
        d[:, :2] -= L * np.round(d[:, :2] / L)  # nearest image (a fiber's half-projection is <= L / 2)
        a = d @ t
        inside |= (np.abs(a) <= 0.5 * ell) & (np.einsum("ij,ij->i", d, d) - a * a < R * R)
    return float(inside.mean())
