"""Validation meshes of the ray tracer: a flat plane and a straight yarn, limits with known answers."""

from __future__ import annotations

import numpy as np

from simulate.geometry.mesh import FabricMesh, grid_faces

__all__ = ["flat_mesh", "straight_yarn_mesh"]


def straight_yarn_mesh(radius_um: float, lx: float, ly: float, n_s: int = 4, sides: int = 72) -> FabricMesh:
    """One straight circular yarn along x at ``y = ly / 2``, ``z = 0`` (the fiber-model limit)."""
    s = np.linspace(0.0, lx, n_s + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, sides + 1)
    S2, P2 = np.meshgrid(s, phi, indexing="ij")
    S, P = S2.ravel(), P2.ravel()
    v = np.column_stack([S, ly / 2 + radius_um * np.cos(P), radius_um * np.sin(P)])
    nrm = np.column_stack([np.zeros_like(S), np.cos(P), np.sin(P)])
    faces = grid_faces(n_s, sides, 0).astype(np.int32)     # the layout's order, winding outward
    return FabricMesh(
        vertices=v, faces=faces, normals=nrm, tangents=np.tile([1.0, 0.0, 0.0], (v.shape[0], 1)),
        vertex_s=S.copy(), vertex_phi=P.copy(), vertex_yarn=np.zeros(v.shape[0], np.int32),
        face_yarn=np.zeros(len(faces), np.int32), vertex_base=np.zeros(1, np.int64), face_base=np.zeros(1, np.int64),
        n_s=np.array([n_s], np.int32), yarn_length=np.array([lx]), sides=sides, Lx=lx, Ly=ly,
        z_min=-radius_um, z_max=radius_um)


def flat_mesh(lx: float = 100.0, ly: float = 100.0) -> FabricMesh:
    """A flat cell (two triangles at z = 0, normal +z): the Lambertian plane of the tracer's validation."""
    v = np.array([[0, 0, 0], [lx, 0, 0], [lx, ly, 0], [0, ly, 0]], float)
    return FabricMesh(
        vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
        normals=np.tile([0.0, 0.0, 1.0], (4, 1)), tangents=np.tile([1.0, 0.0, 0.0], (4, 1)),
        vertex_s=v[:, 0].copy(), vertex_phi=np.zeros(4), vertex_yarn=np.zeros(4, np.int32),
        face_yarn=np.zeros(2, np.int32), vertex_base=np.zeros(1, np.int64), face_base=np.zeros(1, np.int64),
        n_s=np.ones(1, np.int32), yarn_length=np.array([lx]), sides=1, Lx=lx, Ly=ly,
        z_min=0.0, z_max=0.0)
