"""The mesh type of the ray tracer, and the yarn tubes of a woven micro-element as one.

:class:`FabricMesh` is the one mesh the tracer (:mod:`simulate.raytrace`) walks: the tubes of a
periodic cell (a weave's yarns, a felt's fibres, a validation shape) in the grid layout of
:mod:`simulate.geometry.weave`'s docstring. :func:`mesh` triangulates each yarn of a
:class:`simulate.geometry.weave.Weave` as a tube with vertex normals and the yarn tangent at each
vertex (which orients the fiber BRDF); the felt (:mod:`simulate.geometry.felt`) and the validation
meshes (:mod:`simulate.geometry.validation`) build the same type; the tracer tiles it periodically.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gonio.data.dataset import atomic_write
from simulate.geometry.weave import Weave, WeaveError

if TYPE_CHECKING:
    import trimesh

__all__ = ["FabricMesh", "grid_faces", "mesh"]


@dataclass(frozen=True, eq=False)
class FabricMesh:
    """Triangulated tubes of a periodic cell: a weave's yarns, a felt's fibres (layout: :mod:`simulate.geometry.weave`).

    A tube is a "yarn" of the layout: a weave's yarn, or one image of a felt's fibre.

    Attributes
    ----------
    vertices, normals, tangents : (V, 3) float64
        Positions; unit outward analytic normals; unit yarn tangents (along increasing ``s``).
    faces : (F, 3) int32
        Counter-clockwise seen from outside.
    vertex_yarn : (V,) int32; vertex_s, vertex_phi : (V,) float64
        Yarn index and surface parameters of each vertex.
    face_yarn : (F,) int32
    vertex_base, face_base : (n_yarns,) int64
        First vertex and first face of each yarn.
    n_s : (n_yarns,) int32
        Intervals along each yarn; yarn_length : (n_yarns,) float64, ``Lx`` or ``Ly``.
    sides : int
        Intervals around the section.
    Lx, Ly, z_min, z_max : float
        Cell size and the z bounds of all vertices.
    yarn_radius_um : float or None
        The tubes' one radius when they have one (a felt's fibres); None: the tracer takes
        ``sqrt(a b)`` of the first yarn's section.
    open_fibers : bool
        False for a weave's yarns (periodic: ``s`` runs along ``x`` or ``y`` over the cell); True for a
        felt's fibres (``s`` the arc length along an open tube: the tracer clamps exits to its ends and
        puts rays that leave from an image outside the cell back into it).
    info : dict
        What the builder reports (a felt: fibres, images, thickness, volume fraction...); empty for a weave.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    vertex_yarn: np.ndarray
    vertex_s: np.ndarray
    vertex_phi: np.ndarray
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
    yarn_radius_um: float | None = None
    open_fibers: bool = False
    info: dict = field(default_factory=dict)

    def vertex_index(self, yarn: int, i_s: Any, i_phi: Any) -> Any:
        """Vertex index of grid point ``(i_s, i_phi)`` of a yarn (the layout contract)."""
        return self.vertex_base[yarn] + np.asarray(i_s) * (self.sides + 1) + np.asarray(i_phi)

    def to_trimesh(self) -> trimesh.Trimesh:
        """A :class:`trimesh.Trimesh` of the same vertices and faces.

        Not merged or reordered, with the analytic vertex normals.
        """
        import trimesh

        return trimesh.Trimesh(vertices=self.vertices, faces=self.faces, vertex_normals=self.normals,
                               process=False, validate=False)

    def export(self, path: str | Path) -> Path:
        """Write the mesh as PLY or OBJ (chosen by the suffix, through trimesh); returns the path.

        The write is atomic: the mesh goes to a temporary file in the same folder
        (``.NAME.XXXXXXXX.tmp``), is flushed to disk and renamed over ``path``; on any failure (a
        full disk, an interrupt) the temporary file is removed and ``path`` is left as it was, so a
        truncated mesh is never left under the requested name.

        Raises
        ------
        WeaveError
            For a suffix other than ``.ply``/``.obj``, or when the file cannot be written.
        """
        path = Path(path)
        kind = path.suffix.lower().lstrip(".")
        if kind not in ("ply", "obj"):
            raise WeaveError(f"{path}: unknown mesh format {path.suffix or '(no suffix)'!r}; "
                             f"use a .ply or .obj file name")
        try:
            atomic_write(path, lambda handle: self.to_trimesh().export(handle, file_type=kind))
        except OSError as exc:
            raise WeaveError(f"{path}: cannot write the mesh ({exc.strerror or exc}); nothing was "
                             f"written under that name") from None
        return path


def _yarn_grid(weave: Weave, yarn: int, n_s: int) -> tuple[np.ndarray, ...]:
    """Vertices, normals, tangents, s and phi of one yarn's (n_s + 1) x (sides + 1) grid."""
    L = weave.yarn_length(yarn)
    s = np.arange(n_s + 1) * (L / n_s)
    s[-1] = L
    spline = weave.centre_line(yarn)
    z, dz = spline(s), spline(s, 1)
    # exact periodicity: the end ring is the start ring shifted by L, bit for bit
    z[-1], dz[-1] = z[0], dz[0]
    phi = 2.0 * np.pi * np.arange(weave.sides + 1) / weave.sides
    cos, sin = np.cos(phi), np.sin(phi)
    cos[-1], sin[-1] = cos[0], sin[0]  # the seam ring coincides exactly with the first one

    a, b = 0.5 * weave.width_um, 0.5 * weave.height_um
    S, C = np.meshgrid(s, cos, indexing="ij")
    Z, Sn = np.meshgrid(z, sin, indexing="ij")
    DZ = np.broadcast_to(dz[:, None], S.shape)
    zeros = np.zeros_like(S)
    if weave.is_warp(yarn):
        y_c = (yarn + 0.5) * weave.spacing_um
        P = np.stack([S, y_c + a * C, Z + b * Sn], axis=-1)
        N = np.stack([-a * DZ * Sn, b * C, a * Sn], axis=-1)          # dP/dphi x dP/ds
        T = np.stack([np.ones_like(S), zeros, DZ], axis=-1)
    else:
        x_c = (yarn - weave.n_warp + 0.5) * weave.spacing_um
        P = np.stack([x_c - a * C, S, Z + b * Sn], axis=-1)
        N = np.stack([-b * C, -a * DZ * Sn, a * Sn], axis=-1)         # dP/dphi x dP/ds
        T = np.stack([zeros, np.ones_like(S), DZ], axis=-1)
    N /= np.linalg.norm(N, axis=-1, keepdims=True)
    T /= np.linalg.norm(T, axis=-1, keepdims=True)
    PHI = np.broadcast_to(phi[None, :], S.shape)
    return (P.reshape(-1, 3), N.reshape(-1, 3), T.reshape(-1, 3), S.reshape(-1), PHI.reshape(-1))


def grid_faces(n_s: int, sides: int, base: int) -> np.ndarray:
    """Faces of one yarn's grid in the contract's order (two per quad, winding outward)."""
    i_s, i_phi = np.meshgrid(np.arange(n_s), np.arange(sides), indexing="ij")
    v00 = base + i_s * (sides + 1) + i_phi
    v10, v01 = v00 + (sides + 1), v00 + 1
    v11 = v10 + 1
    # the natural order (v00, v10, v11) winds inward for this parametrisation: last two swapped
    first = np.stack([v00, v11, v10], axis=-1)
    second = np.stack([v00, v01, v11], axis=-1)
    return np.stack([first, second], axis=2).reshape(-1, 3)


def mesh(weave: Weave) -> FabricMesh:
    """Triangulate the yarn tubes of a micro-element (layout and conventions: :mod:`simulate.geometry.weave`).

    The mesh has ``4 sides points_per_span n_warp n_weft`` triangles, at most
    :data:`simulate.geometry.weave.MAX_TRIANGLES` (2 million, about 0.27 GiB at the peak of this
    function): the :class:`~simulate.geometry.weave.Weave` refuses a larger one when it is made.

    Examples
    --------
    >>> from simulate.geometry.weave import preset
    >>> m = mesh(preset("plain", points_per_span=4, sides=8))
    >>> m.vertices.shape, m.faces.shape       # 4 yarns x (8 + 1) x (8 + 1); 4 x 2 x 8 x 8
    ((324, 3), (512, 3))
    >>> m.z_min, m.z_max
    (-100.0, 100.0)
    """
    n_y = weave.n_yarns
    n_s = np.array([weave.points_per_span * weave.crossings(y) for y in range(n_y)], dtype=np.int32)
    ring = weave.sides + 1
    vertex_count = (n_s.astype(np.int64) + 1) * ring
    face_count = 2 * n_s.astype(np.int64) * weave.sides
    vertex_base = np.concatenate([[0], np.cumsum(vertex_count)[:-1]]).astype(np.int64)
    face_base = np.concatenate([[0], np.cumsum(face_count)[:-1]]).astype(np.int64)

    parts = [_yarn_grid(weave, y, int(n_s[y])) for y in range(n_y)]
    vertices = np.concatenate([p[0] for p in parts])
    faces = np.concatenate([grid_faces(int(n_s[y]), weave.sides, int(vertex_base[y])) for y in range(n_y)])
    return FabricMesh(
        vertices=vertices,
        faces=faces.astype(np.int32),
        normals=np.concatenate([p[1] for p in parts]),
        tangents=np.concatenate([p[2] for p in parts]),
        vertex_yarn=np.repeat(np.arange(n_y, dtype=np.int32), vertex_count),
        vertex_s=np.concatenate([p[3] for p in parts]),
        vertex_phi=np.concatenate([p[4] for p in parts]),
        face_yarn=np.repeat(np.arange(n_y, dtype=np.int32), face_count),
        vertex_base=vertex_base,
        face_base=face_base,
        n_s=n_s,
        yarn_length=np.array([weave.yarn_length(y) for y in range(n_y)], dtype=np.float64),
        sides=int(weave.sides),
        Lx=float(weave.Lx),
        Ly=float(weave.Ly),
        z_min=float(vertices[:, 2].min()),
        z_max=float(vertices[:, 2].max()),
    )
