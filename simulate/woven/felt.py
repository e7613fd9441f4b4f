r"""A nonwoven felt for the woven-fabric tracer: a random layer of straight fibers in a periodic cell.

The summation's felt (:func:`simulate.fabric.structure.felt_facets`, docs/physics.md 6.2) has fibers
whose in-plane direction is uniform in ``[0, 180)`` deg and whose inclination ``epsilon`` out of the
plane is normal with standard deviation ``felt_spread_deg`` (truncated at +-80 deg). Here the same
fibers are built as geometry and traced on Embree like the weave's yarns:

* **Cell**: ``[0, L) x [0, L)`` with ``L = 40 R`` (``R`` the fiber radius), periodic as the weave's
  micro-element (:mod:`simulate.woven.scene`).
* **Fibers**: straight circular tubes of radius ``R``, length ``l = 40 R``, each with a uniform
  random centre (x, y in the cell; z uniform in the slab ``[-H, 0]``, ``H = 2 R x layers``) and a
  direction drawn from the distribution above. A fiber that crosses the cell's sides is also put in
  at its periodic images (shifted by ``+-L``), so the cell tiles the plane seamlessly.
* **How many**: the summation's felt is ``layers`` (``structure.layers``, default 10) layers of
  parallel fibers at spacing ``d = 2 R spacing_ratio`` (the packing fraction's); here the fibers'
  projected area ``2 R l cos(epsilon)`` adds up to the same ``layers L^2 / spacing_ratio``. The fibers
  are placed independently, so they interpenetrate where they cross (the tracer's interpenetration
  rule, docs/physics.md 6, handles light inside two fibers).
* **Ends**: the tubes are open. An end is ``R / l = 2.5 %`` of a fiber's surface; light that enters
  one meets the tube's inside and is taken into the fiber's volume (the interpenetration rule again).
* **Mesh**: the weave mesh's contract (:mod:`simulate.fabric.weave`): one "yarn" per fiber image,
  ``(n_s + 1) x (sides + 1)`` vertices, ``s`` the arc length along the fiber (``open_fibers``: the
  tracer clamps exits to the tube's ends instead of wrapping them round a periodic yarn, and puts
  rays that leave from an image outside the cell back into it), vertex normals radial; no twist.

The yarn table is the fiber's own (``r_yarn = R``: the exit offsets need no scaling).

Limits: straight fibers (a real felt's fibers curl), random overlaps instead of packed contacts,
a cell of 40 R (about 20 fibers across): the spread of the fibers' structure between seeds is part
of a run's reproducibility at a fixed seed, not of its reported error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["FeltMesh", "felt_mesh", "CELL_RADII", "LENGTH_RADII"]

#: the cell's side and the fibers' length, in fiber radii
CELL_RADII = 40.0
LENGTH_RADII = 40.0


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


def felt_mesh(spec: object, radius_um: float, seed: int = 0, *, sides: int = 48, n_s: int = 4) -> FeltMesh:
    """The felt of ``spec`` (:class:`simulate.fabric.structure.StructureSpec`, ``kind = "nonwoven"``) for
    fibers of radius ``radius_um``: random fibers from the stream ``seed`` (module docstring)."""
    from simulate.fabric.mesh import _grid_faces

    R = float(radius_um)
    L = CELL_RADII * R
    ell = LENGTH_RADII * R
    layers = int(getattr(spec, "layers", 0)) or 10
    ratio = float(getattr(spec, "spacing_ratio", 1.0))
    spread = math.radians(float(getattr(spec, "felt_spread_deg", 20.0)))
    H = 2.0 * R * layers
    rng = np.random.default_rng([int(seed), 0x7E17])
    target = layers * L * L / ratio           # the layers' projected fiber area
    area = 0.0
    fibers = []
    while area < target:
        az = rng.uniform(0.0, math.pi)
        eps = rng.normal(0.0, spread) if spread > 0 else 0.0
        while abs(eps) > math.radians(80.0):
            eps = rng.normal(0.0, spread)
        t = np.array([math.cos(eps) * math.cos(az), math.cos(eps) * math.sin(az), math.sin(eps)])
        c = np.array([rng.uniform(0.0, L), rng.uniform(0.0, L), -H * rng.uniform(0.0, 1.0)])
        fibers.append((c, t))
        area += 2.0 * R * ell * math.cos(eps)
    verts, norms, tans, ss, phis, yarn_len = [], [], [], [], [], []
    for c, t in fibers:
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
    faces = np.concatenate([_grid_faces(n_s, sides, int(vertex_base[y])) for y in range(n_y)]).astype(np.int32)
    vertices = np.concatenate(verts)
    return FeltMesh(
        vertices=vertices, faces=faces, normals=np.concatenate(norms), tangents=np.ascontiguousarray(np.concatenate(tans)),
        vertex_s=np.concatenate(ss), vertex_phi=np.concatenate(phis),
        vertex_yarn=np.repeat(np.arange(n_y, dtype=np.int32), ring),
        face_yarn=np.repeat(np.arange(n_y, dtype=np.int32), 2 * n_s * sides),
        vertex_base=vertex_base, face_base=face_base, n_s=np.full(n_y, n_s, dtype=np.int32),
        yarn_length=np.array(yarn_len, float), sides=int(sides), Lx=L, Ly=L,
        z_min=float(vertices[:, 2].min()), z_max=float(vertices[:, 2].max()), yarn_radius_um=R,
        info={"fibers": len(fibers), "images": n_y, "cell_um": L, "fiber_length_um": ell, "slab_um": H,
              "layers": layers, "spread_deg": math.degrees(spread), "triangles": int(faces.shape[0]),
              "volume_fraction": len(fibers) * math.pi * R * R * ell / (L * L * H), "seed": int(seed)})
