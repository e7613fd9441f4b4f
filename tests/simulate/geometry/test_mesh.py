"""simulate.geometry.mesh: the grid-layout contract, exact periodic continuity, outward normals and
winding, tangents, and export through trimesh."""

from __future__ import annotations

import numpy as np
import pytest

from simulate.geometry.mesh import mesh
from simulate.geometry.weave import PRESETS, Weave, WeaveError, preset

WEAVES = {
    **{name: preset(name, points_per_span=5, sides=7) for name in PRESETS},
    "irregular": Weave([[1, 0, 0], [0, 1, 1], [1, 1, 0], [0, 0, 1]], spacing_um=200, width_um=200,
                       height_um=70, crimp=0.6, points_per_span=3, sides=5),
}


@pytest.fixture(params=sorted(WEAVES))
def case(request):
    w = WEAVES[request.param]
    return w, mesh(w)


def _ring(m, yarn, i_s):
    start = m.vertex_base[yarn] + i_s * (m.sides + 1)
    return slice(int(start), int(start) + m.sides + 1)


def test_dtypes_and_shapes(case):
    w, m = case
    V, F = len(m.vertices), len(m.faces)
    assert m.vertices.shape == (V, 3) and m.vertices.dtype == np.float64
    assert m.faces.shape == (F, 3) and m.faces.dtype == np.int32
    for name in ("normals", "tangents"):
        assert getattr(m, name).shape == (V, 3) and getattr(m, name).dtype == np.float64
    assert m.vertex_yarn.shape == (V,) and m.vertex_yarn.dtype == np.int32
    assert m.vertex_s.dtype == np.float64 and m.vertex_phi.dtype == np.float64
    assert m.face_yarn.shape == (F,) and m.face_yarn.dtype == np.int32
    assert m.vertex_base.dtype == np.int64 and m.face_base.dtype == np.int64
    assert m.vertex_base.shape == m.face_base.shape == (w.n_yarns,)
    assert m.n_s.dtype == np.int32 and m.yarn_length.dtype == np.float64
    assert isinstance(m.sides, int) and m.sides == w.sides
    assert (m.Lx, m.Ly) == (w.Lx, w.Ly)
    assert m.z_min == m.vertices[:, 2].min() and m.z_max == m.vertices[:, 2].max()
    assert m.faces.min() >= 0 and m.faces.max() < V


def test_grid_layout_contract(case):
    w, m = case
    ring = w.sides + 1
    faces = []
    for y in range(w.n_yarns):
        n_s = w.points_per_span * (w.n_weft if y < w.n_warp else w.n_warp)
        L = w.Lx if y < w.n_warp else w.Ly
        assert m.n_s[y] == n_s and m.yarn_length[y] == L
        base = m.vertex_base[y]
        assert base == sum((m.n_s[k] + 1) * ring for k in range(y))
        assert m.face_base[y] == sum(2 * m.n_s[k] * w.sides for k in range(y))
        block = slice(int(base), int(base) + (n_s + 1) * ring)
        assert (m.vertex_yarn[block] == y).all()
        i_s, i_phi = np.divmod(np.arange((n_s + 1) * ring), ring)
        np.testing.assert_allclose(m.vertex_s[block], i_s * L / n_s, rtol=0, atol=1e-9)
        np.testing.assert_allclose(m.vertex_phi[block], 2 * np.pi * i_phi / w.sides, rtol=0, atol=1e-12)
        v = lambda a, b, base=base: base + a * ring + b  # noqa: E731 - the contract's formula
        for a in range(n_s):
            for b in range(w.sides):
                k = m.face_base[y] + 2 * (a * w.sides + b)
                # documented winding (all yarns): the natural order with the last two swapped
                assert m.faces[k].tolist() == [v(a, b), v(a + 1, b + 1), v(a + 1, b)]
                assert m.faces[k + 1].tolist() == [v(a, b), v(a, b + 1), v(a + 1, b + 1)]
                assert m.face_yarn[k] == m.face_yarn[k + 1] == y
                faces += [m.faces[k], m.faces[k + 1]]
    assert len(faces) == len(m.faces)          # the blocks tile the face array


def test_vertices_are_the_documented_surface(case):
    w, m = case
    a, b = w.width_um / 2, w.height_um / 2
    for y in range(w.n_yarns):
        sel = m.vertex_yarn == y
        s, phi = m.vertex_s[sel], m.vertex_phi[sel]
        z = w.centre_line(y)(s) + b * np.sin(phi)
        if y < w.n_warp:
            expected = np.stack([s, (y + 0.5) * w.spacing_um + a * np.cos(phi), z], axis=1)
        else:
            expected = np.stack([(y - w.n_warp + 0.5) * w.spacing_um - a * np.cos(phi), s, z], axis=1)
        np.testing.assert_allclose(m.vertices[sel], expected, rtol=0, atol=1e-9)


def test_end_ring_is_the_start_ring_shifted_by_L_exactly(case):
    w, m = case
    for y in range(w.n_yarns):
        axis = 0 if y < w.n_warp else 1
        first, last = _ring(m, y, 0), _ring(m, y, int(m.n_s[y]))
        shifted = m.vertices[first].copy()
        assert (shifted[:, axis] == 0.0).all()          # the tube starts in the face plane
        shifted[:, axis] += m.yarn_length[y]
        assert np.array_equal(m.vertices[last], shifted)
        assert np.array_equal(m.normals[last], m.normals[first])
        assert np.array_equal(m.tangents[last], m.tangents[first])
        assert (m.vertex_s[last] == m.yarn_length[y]).all()
        # the seam column phi = 2 pi coincides exactly with phi = 0
        seam = m.vertex_base[y] + np.arange(m.n_s[y] + 1) * (m.sides + 1)
        assert np.array_equal(m.vertices[seam + m.sides], m.vertices[seam])
        assert np.array_equal(m.normals[seam + m.sides], m.normals[seam])


def test_neighbouring_micro_elements_join_without_a_gap(case):
    """Tiling: the end ring of a yarn is the start ring of the same yarn in the next micro-element."""
    w, m = case
    for y in range(w.n_yarns):
        shift = np.array([m.Lx, 0, 0]) if y < w.n_warp else np.array([0, m.Ly, 0])
        assert np.array_equal(m.vertices[_ring(m, y, 0)] + shift, m.vertices[_ring(m, y, int(m.n_s[y]))])


def test_normals_are_unit_and_outward(case):
    w, m = case
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-12)
    for y in range(w.n_yarns):
        sel = m.vertex_yarn == y
        s = m.vertex_s[sel]
        zc = w.centre_line(y)(s)
        if y < w.n_warp:
            centre = np.stack([s, np.full_like(s, (y + 0.5) * w.spacing_um), zc], axis=1)
        else:
            centre = np.stack([np.full_like(s, (y - w.n_warp + 0.5) * w.spacing_um), s, zc], axis=1)
        assert (np.einsum("ij,ij->i", m.normals[sel], m.vertices[sel] - centre) > 0).all()


def test_normals_agree_with_the_surface_and_the_winding(case):
    w, m = case
    tri = m.vertices[m.faces]
    face_normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    mean_vertex_normal = m.normals[m.faces].mean(axis=1)
    assert (np.einsum("ij,ij->i", face_normal, mean_vertex_normal) > 0).all()
    # analytic normals are perpendicular to the surface: to the tangent and to dP/dphi
    assert np.abs(np.einsum("ij,ij->i", m.normals, m.tangents)).max() < 1e-12


def test_tangents_follow_the_centre_line(case):
    w, m = case
    np.testing.assert_allclose(np.linalg.norm(m.tangents, axis=1), 1.0, atol=1e-12)
    for y in range(w.n_yarns):
        sel = m.vertex_yarn == y
        dz = w.centre_line(y)(m.vertex_s[sel], 1)
        one, zero = np.ones_like(dz), np.zeros_like(dz)
        t = np.stack([one, zero, dz] if y < w.n_warp else [zero, one, dz], axis=1)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        np.testing.assert_allclose(m.tangents[sel], t, atol=1e-12)
        # phi-independent: equal around each ring
        rings = m.tangents[sel].reshape(int(m.n_s[y]) + 1, m.sides + 1, 3)
        assert np.array_equal(rings, np.broadcast_to(rings[:, :1], rings.shape))


def test_plain_weave_bounds():
    m = mesh(preset("plain", spacing_um=300, width_um=250, height_um=100, crimp=1.0))
    # centre lines at +-50 through the crossings (spline of a plain weave is a pure cosine-like
    # curve reaching its extremes there), plus the semi-axis 50
    assert (m.z_min, m.z_max) == (-100.0, 100.0)
    assert m.Lx == m.Ly == 600.0


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".PLY"])
def test_export_round_trip_through_trimesh(tmp_path, suffix):
    import trimesh

    m = mesh(preset("twill", points_per_span=3, sides=6))
    t = m.to_trimesh()
    assert len(t.vertices) == len(m.vertices) and len(t.faces) == len(m.faces)
    np.testing.assert_array_equal(t.faces, m.faces)
    np.testing.assert_allclose(t.vertex_normals, m.normals)
    path = m.export(tmp_path / f"twill{suffix}")
    assert path.is_file()
    back = trimesh.load(path, process=False)
    assert len(back.vertices) == len(m.vertices)
    assert len(back.faces) == len(m.faces)
    np.testing.assert_allclose(back.vertices, m.vertices, atol=1e-5)


def test_export_rejects_an_unknown_suffix_naming_the_path(tmp_path):
    m = mesh(preset("plain", points_per_span=2, sides=4))
    target = tmp_path / "mesh.stl"
    with pytest.raises(WeaveError, match=r"mesh\.stl: unknown mesh format '\.stl'; use a \.ply or \.obj"):
        m.export(target)
    with pytest.raises(WeaveError, match="unknown mesh format '\\(no suffix\\)'"):
        m.export(tmp_path / "mesh")
    with pytest.raises(WeaveError, match="cannot write the mesh"):
        m.export(tmp_path / "no" / "such" / "dir" / "mesh.ply")
    assert not target.exists()


def _tube_builders():
    """The tubes of every builder other than the weave's, each a FabricMesh: a felt, a straight yarn."""
    from simulate.fabric.structure import StructureSpec
    from simulate.geometry.felt import felt_mesh
    from simulate.geometry.validation import straight_yarn_mesh

    felt = felt_mesh(StructureSpec(kind="nonwoven", layers=1, felt_spread_deg=15.0), 10.0, seed=2, sides=6, n_s=3)
    return {"felt": felt, "straight yarn": straight_yarn_mesh(10.0, 40.0, 60.0, n_s=3, sides=6)}


@pytest.mark.parametrize("name", ["felt", "straight yarn"])
def test_every_builder_gives_one_mesh_type_in_the_layout(name):
    """The felt and the validation yarn are FabricMesh in the weave's grid layout: each tube's vertex at
    (i_s, i_phi) sits at s = i_s L / n_s, phi = 2 pi i_phi / sides, and its faces are the layout's."""
    from simulate.geometry.mesh import FabricMesh, grid_faces

    m = _tube_builders()[name]
    assert type(m) is FabricMesh
    ring = m.sides + 1
    for y in range(len(m.vertex_base)):
        n_s = int(m.n_s[y])
        i_s, i_phi = np.meshgrid(np.arange(n_s + 1), np.arange(ring), indexing="ij")
        idx = m.vertex_index(y, i_s, i_phi)
        assert np.allclose(m.vertex_s[idx], i_s * m.yarn_length[y] / n_s, rtol=0, atol=1e-9)
        assert np.allclose(m.vertex_phi[idx], 2.0 * np.pi * i_phi / m.sides, rtol=0, atol=1e-12)
        assert np.all(m.vertex_yarn[idx] == y)
        first = int(m.face_base[y])
        assert np.array_equal(m.faces[first:first + 2 * n_s * m.sides],
                              grid_faces(n_s, m.sides, int(m.vertex_base[y])))
    # the tracer tells the felt's open fibres from periodic yarns by the mesh alone
    assert m.open_fibers is (name == "felt")
    assert m.yarn_radius_um == (10.0 if name == "felt" else None)


def test_the_weave_mesh_is_periodic_yarns_of_no_stated_radius():
    m = mesh(preset("plain", points_per_span=2, sides=4))
    assert m.open_fibers is False and m.yarn_radius_um is None and m.info == {}
