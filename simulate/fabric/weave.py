"""Woven-fabric geometry: the weave matrix, yarn centre lines and the yarn tubes of a micro-element.

docs/physics.md §6 (Monte Carlo ray tracing of a woven fabric, "Geometry"): the weave is a matrix
(1 = warp over weft); it gives the control points of each yarn's centre line, a periodic cubic
spline interpolates them with a chosen number of intermediate points, and the yarns are
triangulated as tubes with vertex normals and the yarn tangent at each vertex (which orients the
fiber BRDF). The unit cell of the pattern is the micro-element, tiled periodically by the tracer.

Conventions (fabric frame: ``z`` = fabric normal, ``x`` = warp direction; lengths in um)
----------------------------------------------------------------------------------------
``matrix[j, i] = 1``: warp yarn ``j`` lies OVER weft yarn ``i`` at their crossing. Warp ``j`` runs
along ``x`` at ``y_j = (j + 1/2) p``, weft ``i`` along ``y`` at ``x_i = (i + 1/2) p`` (``p`` =
``spacing_um``). Micro-element ``[0, Lx) x [0, Ly)``, ``Lx = n_weft p``, ``Ly = n_warp p``.
Yarn index: warps ``0 .. n_warp - 1``, then wefts ``n_warp .. n_warp + n_weft - 1``.

Centre line of warp ``j``: ``z_c(x)``, the periodic cubic spline (period ``Lx``) through
``(x_i, +c h/2)`` where ``matrix[j, i] = 1`` and ``(x_i, -c h/2)`` where 0 (``c`` = crimp,
``h`` = ``height_um``); weft ``i``: ``z_c(y)`` through ``(y_j, -c h/2)`` where ``matrix[j, i] = 1``
and ``(y_j, +c h/2)`` where 0. So at every crossing the warp centre is above the weft centre iff
the matrix says 1 (with ``c = 1`` the two tubes just touch there).

Tube: an ellipse with semi-axes ``a = width/2`` (horizontal) and ``b = height/2`` (vertical) in the
vertical plane perpendicular to the yarn's in-plane direction, ``s`` = coordinate along the run::

    warp j:  P(s, phi) = (s,                 y_j + a cos(phi),  z_c(s) + b sin(phi))
    weft i:  P(s, phi) = (x_i - a cos(phi),  s,                 z_c(s) + b sin(phi))

The weft is the warp turned by +90 degrees about ``z`` (the horizontal axis of the ellipse is
``z x t``), so both families share one orientation and one winding rule. Because the section is
vertical, a warp tube ends exactly in the planes ``x = 0`` and ``x = Lx`` (a weft in ``y = 0``,
``y = Ly``) and the end ring is the start ring shifted by ``L``: continuity across the faces of
the periodic micro-element is exact.

Outward normal ``n = dP/dphi x dP/ds`` normalised (warp ``(-a z' sin, b cos, a sin)``, weft
``(-b cos, -a z' sin, a sin)``); tangent ``t = (1, 0, z')`` (warp), ``(0, 1, z')`` (weft), normalised.

Mesh layout (the contract with :mod:`simulate.woven.scene`)
-------------------------------------------------------
Yarn ``y`` is a grid of ``(n_s + 1) x (sides + 1)`` vertices, ``n_s = points_per_span x``
(crossings along the yarn); vertex ``vertex_base[y] + i_s (sides + 1) + i_phi`` is at
``s = i_s L / n_s`` (``i_s = 0 .. n_s``, both ends) and ``phi = 2 pi i_phi / sides``
(``i_phi = 0 .. sides``, seam duplicated). Quad ``(i_s, i_phi)`` has the two faces
``face_base[y] + 2 (i_s sides + i_phi)`` and ``+ 1``. The natural order
``(v(i_s, i_phi), v(i_s+1, i_phi), v(i_s+1, i_phi+1))`` winds about ``dP/ds x dP/dphi``, which
points INTO the tube for both families with the parametrisation above; so, for warps and wefts
alike, the last two vertices of each triangle are swapped:

    face 2k     = (v(i_s, i_phi), v(i_s+1, i_phi+1), v(i_s+1, i_phi))
    face 2k + 1 = (v(i_s, i_phi), v(i_s, i_phi+1),   v(i_s+1, i_phi+1))

which is counter-clockwise seen from outside (right-hand normal out of the yarn).

References
----------
Ravi Nielsen et al., *Weaving Information File (WIF) Specification*, version 1.1, 20 April 1997.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.interpolate import CubicSpline

if TYPE_CHECKING:
    import trimesh

__all__ = [
    "DEFAULT_CRIMP",
    "DEFAULT_HEIGHT_UM",
    "DEFAULT_POINTS_PER_SPAN",
    "DEFAULT_SIDES",
    "DEFAULT_SPACING_UM",
    "DEFAULT_WIDTH_UM",
    "PRESETS",
    "Weave",
    "WeaveError",
    "WeaveMesh",
    "mesh",
    "preset",
    "read_wif",
    "weave_from_wif",
]

# The shipped red-cotton weave (simulate/configs/red-cotton.toml): the defaults of a config
# without these fields.
DEFAULT_SPACING_UM = 300.0
DEFAULT_WIDTH_UM = 250.0
DEFAULT_HEIGHT_UM = 100.0
DEFAULT_CRIMP = 1.0
DEFAULT_POINTS_PER_SPAN = 8
DEFAULT_SIDES = 16

#: Named weaves (rows = warp yarns, columns = weft yarns, 1 = warp over weft).
#: ``satin`` is the regular 5-end warp-faced satin with move (counter) 2: warp ``j`` goes under
#: weft ``2 j mod 5`` only, so every warp floats over 4 wefts and every weft is bound by exactly
#: one warp (2 and 5 are coprime); its transpose ``1 - matrix`` would be the weft-faced sateen.
PRESETS: dict[str, list[list[int]]] = {
    "plain": [[1, 0], [0, 1]],
    "twill": [[1, 1, 0, 0], [0, 1, 1, 0], [0, 0, 1, 1], [1, 0, 0, 1]],
    "satin": [[0 if i == (2 * j) % 5 else 1 for i in range(5)] for j in range(5)],
}


class WeaveError(ValueError):
    """A bad weave (matrix, dimensions, WIF file, export path): one line naming the row, column,
    line or field."""


# ------------------------------------------------------------------------------------------
# the weave


def _matrix(value: Any) -> np.ndarray:
    """Validate a 0/1 matrix given as nested lists or an array; an int8 array."""
    if isinstance(value, np.ndarray):
        if value.ndim != 2:
            raise WeaveError(f"weave matrix: must be 2-D (rows = warp yarns), got {value.ndim}-D")
        rows = [list(r) for r in value]
    else:
        if not isinstance(value, (list, tuple)) or not all(isinstance(r, (list, tuple, np.ndarray)) for r in value):
            raise WeaveError("weave matrix: must be a list of rows (one per warp yarn) of 0/1 entries")
        rows = [list(r) for r in value]
    if not rows or not rows[0]:
        raise WeaveError("weave matrix: is empty; it needs at least 2 rows and 2 columns")
    for j, row in enumerate(rows):
        if len(row) != len(rows[0]):
            raise WeaveError(f"weave matrix: row {j} has {len(row)} entries, row 0 has {len(rows[0])} "
                             f"(the matrix must be rectangular)")
    for j, row in enumerate(rows):
        for i, x in enumerate(row):
            ok = (not isinstance(x, (bool, np.bool_)) and isinstance(x, (int, float, np.integer, np.floating))
                  and x in (0, 1))
            if not ok:
                raise WeaveError(f"weave matrix: entry at row {j}, column {i} must be 0 or 1, got {x!r}")
    m = np.array(rows, dtype=np.int8)
    for j in range(m.shape[0]):
        if m[j].min() == m[j].max():
            raise WeaveError(f"weave matrix: warp row {j} never interlaces (all {m[j, 0]})")
    for i in range(m.shape[1]):
        if m[:, i].min() == m[:, i].max():
            raise WeaveError(f"weave matrix: weft column {i} never interlaces (all {m[0, i]})")
    m.setflags(write=False)  # the Weave is frozen: its matrix too
    return m


def _positive(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or not value > 0:
        raise WeaveError(f"weave {name} must be a finite number > 0, got {value!r}")
    return float(value)


def _count(name: str, value: Any, least: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not least <= value <= 100_000:
        raise WeaveError(f"weave {name} must be an integer in [{least}, 100000], got {value!r}")
    return int(value)


@dataclass(frozen=True)
class Weave:
    """A woven micro-element: weave matrix and yarn dimensions (see the module docstring).

    Parameters
    ----------
    matrix : array_like of 0/1, shape (n_warp, n_weft)
        ``matrix[j, i] = 1``: warp ``j`` over weft ``i``. Stored as a read-only int8 array. Every
        warp row and weft column must contain both 0 and 1 (else a yarn would not interlace).
    spacing_um : float
        Centre-to-centre distance of neighbouring yarns of one set (warp and weft alike).
    width_um, height_um : float
        Full axes of the elliptical yarn section (horizontal, vertical); ``width_um <= spacing_um``
        so that the yarns of one set do not overlap.
    crimp : float, (0, 1]
        Amplitude of the centre line's undulation as a fraction of ``height_um / 2``.
    points_per_span : int
        Mesh intervals along a yarn per crossing interval (``n_s = points_per_span x crossings``).
    sides : int
        Mesh intervals around the yarn section (>= 3).

    Raises
    ------
    WeaveError
        Naming the row and column of a bad entry, the row or column that never interlaces, or
        the bad field.

    Examples
    --------
    >>> w = Weave([[1, 0], [0, 1]], spacing_um=300, width_um=250, height_um=100)
    >>> w.n_warp, w.n_weft, w.Lx, w.Ly
    (2, 2, 600.0, 600.0)
    >>> float(w.centre_line(0)(150.0))      # warp 0 over weft 0 at x_0 = 150
    50.0
    """

    matrix: np.ndarray
    spacing_um: float = DEFAULT_SPACING_UM
    width_um: float = DEFAULT_WIDTH_UM
    height_um: float = DEFAULT_HEIGHT_UM
    crimp: float = DEFAULT_CRIMP
    points_per_span: int = DEFAULT_POINTS_PER_SPAN
    sides: int = DEFAULT_SIDES

    def __post_init__(self) -> None:
        # frozen: normalise the fields through object.__setattr__
        set_ = object.__setattr__
        set_(self, "matrix", _matrix(self.matrix))
        for name in ("spacing_um", "width_um", "height_um"):
            set_(self, name, _positive(name, getattr(self, name)))
        crimp = _positive("crimp", self.crimp)
        if crimp > 1.0:
            raise WeaveError(f"weave crimp must be in (0, 1], got {self.crimp!r}")
        set_(self, "crimp", crimp)
        if self.width_um > self.spacing_um:
            raise WeaveError(f"weave width_um ({self.width_um:g}) must be <= spacing_um ({self.spacing_um:g}): "
                             f"neighbouring yarns of one set would overlap")
        set_(self, "points_per_span", _count("points_per_span", self.points_per_span, 1))
        set_(self, "sides", _count("sides", self.sides, 3))

    # a frozen dataclass compares and hashes its fields; an ndarray field needs array equality
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Weave):
            return NotImplemented
        return (np.array_equal(self.matrix, other.matrix)
                and self._scalars() == other._scalars())

    def __hash__(self) -> int:
        return hash((self.matrix.shape, self.matrix.tobytes(), self._scalars()))

    def _scalars(self) -> tuple:
        return (self.spacing_um, self.width_um, self.height_um, self.crimp, self.points_per_span, self.sides)

    @property
    def n_warp(self) -> int:
        """Number of warp yarns (matrix rows)."""
        return int(self.matrix.shape[0])

    @property
    def n_weft(self) -> int:
        """Number of weft yarns (matrix columns)."""
        return int(self.matrix.shape[1])

    @property
    def n_yarns(self) -> int:
        """``n_warp + n_weft``."""
        return self.n_warp + self.n_weft

    @property
    def Lx(self) -> float:
        """Micro-element size along x (warp direction): ``n_weft * spacing_um``."""
        return self.n_weft * self.spacing_um

    @property
    def Ly(self) -> float:
        """Micro-element size along y (weft direction): ``n_warp * spacing_um``."""
        return self.n_warp * self.spacing_um

    def is_warp(self, yarn: int) -> bool:
        """Whether yarn index ``yarn`` is a warp (``0 .. n_warp - 1``)."""
        self._check_yarn(yarn)
        return yarn < self.n_warp

    def yarn_length(self, yarn: int) -> float:
        """Length of the yarn's run in the micro-element: ``Lx`` (warp) or ``Ly`` (weft)."""
        return self.Lx if self.is_warp(yarn) else self.Ly

    def crossings(self, yarn: int) -> int:
        """Number of crossings along the yarn: ``n_weft`` for a warp, ``n_warp`` for a weft."""
        return self.n_weft if self.is_warp(yarn) else self.n_warp

    def _check_yarn(self, yarn: int) -> None:
        if not 0 <= yarn < self.n_yarns:
            raise IndexError(f"yarn index {yarn} out of range 0..{self.n_yarns - 1}")

    def control_points(self, yarn: int) -> tuple[np.ndarray, np.ndarray]:
        """Knots ``s`` (the crossings, plus the periodic repeat) and centre heights ``z`` of a yarn."""
        amplitude = 0.5 * self.crimp * self.height_um
        if self.is_warp(yarn):
            over = self.matrix[yarn, :]
            z = np.where(over == 1, amplitude, -amplitude)
        else:
            over = self.matrix[:, yarn - self.n_warp]
            z = np.where(over == 1, -amplitude, amplitude)  # warp over = weft under
        s = (np.arange(over.size + 1) + 0.5) * self.spacing_um
        s[-1] = s[0] + self.yarn_length(yarn)
        return s, np.append(z, z[0]).astype(float)

    def centre_line(self, yarn: int) -> CubicSpline:
        """The yarn's centre height ``z_c(s)``: periodic cubic spline (period ``L``) through its
        control points; it extrapolates periodically, so it may be evaluated on ``[0, L]``."""
        s, z = self.control_points(yarn)
        return CubicSpline(s, z, bc_type="periodic")


# ------------------------------------------------------------------------------------------
# the mesh


@dataclass(frozen=True, eq=False)
class WeaveMesh:
    """Triangulated yarn tubes of a micro-element (layout in the module docstring).

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
        Micro-element size and the z bounds of all vertices.
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

    def vertex_index(self, yarn: int, i_s: Any, i_phi: Any) -> Any:
        """Vertex index of grid point ``(i_s, i_phi)`` of a yarn (the layout contract)."""
        return self.vertex_base[yarn] + np.asarray(i_s) * (self.sides + 1) + np.asarray(i_phi)

    def to_trimesh(self) -> trimesh.Trimesh:
        """A :class:`trimesh.Trimesh` of the same vertices and faces (not merged or reordered),
        with the analytic vertex normals."""
        import trimesh

        return trimesh.Trimesh(vertices=self.vertices, faces=self.faces, vertex_normals=self.normals,
                               process=False, validate=False)

    def export(self, path: str | Path) -> Path:
        """Write the mesh as PLY or OBJ (chosen by the suffix, through trimesh); returns the path.

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
            self.to_trimesh().export(str(path), file_type=kind)
        except OSError as exc:
            raise WeaveError(f"{path}: cannot write the mesh ({exc.strerror or exc})") from None
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


def _grid_faces(n_s: int, sides: int, base: int) -> np.ndarray:
    """Faces of one yarn's grid in the contract's order (two per quad, winding outward)."""
    i_s, i_phi = np.meshgrid(np.arange(n_s), np.arange(sides), indexing="ij")
    v00 = base + i_s * (sides + 1) + i_phi
    v10, v01 = v00 + (sides + 1), v00 + 1
    v11 = v10 + 1
    # the natural order (v00, v10, v11) winds inward for this parametrisation: last two swapped
    first = np.stack([v00, v11, v10], axis=-1)
    second = np.stack([v00, v01, v11], axis=-1)
    return np.stack([first, second], axis=2).reshape(-1, 3)


def mesh(weave: Weave) -> WeaveMesh:
    """Triangulate the yarn tubes of a micro-element (layout and conventions in the module docstring).

    Examples
    --------
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
    faces = np.concatenate([_grid_faces(int(n_s[y]), weave.sides, int(vertex_base[y])) for y in range(n_y)])
    return WeaveMesh(
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


# ------------------------------------------------------------------------------------------
# presets


def preset(name: str, **params: Any) -> Weave:
    """A :class:`Weave` of a named pattern (:data:`PRESETS`); ``params`` are the other fields.

    Examples
    --------
    >>> preset("twill").matrix.shape
    (4, 4)
    """
    if name not in PRESETS:
        raise WeaveError(f"unknown weave preset {name!r}; choose one of {', '.join(PRESETS)}")
    return Weave(np.array(PRESETS[name], dtype=np.int8), **params)


# ------------------------------------------------------------------------------------------
# WIF (Weaving Information File 1.1)

_SECTION = re.compile(r"^\[([^\]]+)\]$")
_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")


class _Wif:
    """The sections of a WIF file, keys lower-cased, each value with its line number."""

    def __init__(self, path: Path):
        self.name = path.name
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise WeaveError(f"{path}: cannot read the WIF file ({exc.strerror or exc})") from None
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError:  # WIF predates UTF-8: old files are Windows-1252 / Latin-1
            text = raw.decode("latin-1")
        self.sections: dict[str, list[tuple[str, str, int]]] = {}
        self.header_line: dict[str, int] = {}
        current: str | None = None
        for number, line in enumerate(text.splitlines(), start=1):
            line = line.split(";", 1)[0].strip()  # ';' starts a comment
            if not line:
                continue
            header = _SECTION.match(line)
            if header:
                current = header.group(1).strip().lower()
                self.sections.setdefault(current, [])
                self.header_line.setdefault(current, number)
            elif "=" in line:
                if current is None:
                    raise self.error(number, f"{line!r} comes before any [SECTION] header")
                key, value = line.split("=", 1)
                self.sections[current].append((key.strip().lower(), value.strip(), number))
            else:
                raise self.error(number, f"cannot parse {line!r} (expected [SECTION] or key=value)")
        if "wif" not in self.sections:
            raise WeaveError(f"{self.name}: no [WIF] section; not a Weaving Information File")

    def error(self, line: int | None, message: str) -> WeaveError:
        return WeaveError(f"{self.name}, line {line}: {message}" if line else f"{self.name}: {message}")

    def has(self, section: str) -> bool:
        return section in self.sections

    def table(self, section: str) -> dict[str, tuple[str, int]]:
        if section not in self.sections:
            raise self.error(None, f"no [{section.upper()}] section (needed for the drawdown)")
        out: dict[str, tuple[str, int]] = {}
        for key, value, line in self.sections[section]:
            if key in out:
                raise self.error(line, f"[{section.upper()}] {key} repeated (first on line {out[key][1]})")
            out[key] = (value, line)
        return out

    def integer(self, section: str, key: str, least: int = 1) -> int | None:
        entry = self.table(section).get(key)
        if entry is None:
            return None
        value, line = entry
        try:
            number = int(value)
        except ValueError:
            raise self.error(line, f"[{section.upper()}] {key} must be an integer, got {value!r}") from None
        if number < least:
            raise self.error(line, f"[{section.upper()}] {key} must be >= {least}, got {number}")
        return number

    def boolean(self, section: str, key: str, default: bool) -> bool:
        entry = self.table(section).get(key) if self.has(section) else None
        if entry is None:
            return default
        value, line = entry
        if value.lower() in _TRUE:
            return True
        if value.lower() in _FALSE:
            return False
        raise self.error(line, f"[{section.upper()}] {key} must be true or false, got {value!r}")

    def lists(self, section: str, what: str, count: int | None, item: str, limit: int,
              limit_name: str) -> dict[int, tuple[set[int], int]]:
        """``number = a, b, c`` lines of a section: ``{number: ({a, b, c}, line)}``, range-checked."""
        out: dict[int, tuple[set[int], int]] = {}
        for key, (value, line) in self.table(section).items():
            try:
                number = int(key)
            except ValueError:
                raise self.error(line, f"[{section.upper()}] key {key!r} must be a {what} number") from None
            if number < 1 or (count is not None and number > count):
                bound = f" (1..{count})" if count is not None else " (>= 1)"
                raise self.error(line, f"[{section.upper()}] {what} {number} out of range{bound}")
            items: set[int] = set()
            for part in filter(None, (p.strip() for p in value.split(","))):
                try:
                    k = int(part)
                except ValueError:
                    raise self.error(line, f"[{section.upper()}] {what} {number}: {item} {part!r} "
                                           f"is not a number") from None
                if not 1 <= k <= limit:
                    raise self.error(line, f"[{section.upper()}] {what} {number} references {item} {k}, "
                                           f"but {limit_name}={limit}")
                items.add(k)
            out[number] = (items, line)
        return out


def read_wif(path: str | Path) -> np.ndarray:
    """The drawdown of a WIF 1.1 file as a weave matrix (rows = warp threads, columns = picks).

    Warp thread ``j`` (``j + 1`` in the file) raised on pick ``i`` -- it shows on the face, over
    the weft -- gives ``matrix[j, i] = 1``. Read: ``[WEAVING] Shafts`` (and ``Treadles``, ``Rising
    Shed``, default true: the tie-up and lift plan name the shafts that rise, else those that
    sink), ``[WARP] Threads`` and ``[WEFT] Threads`` (else the largest thread/pick number),
    ``[THREADING] thread = shaft(s)`` and either ``[LIFTPLAN] pick = shafts`` (used when present)
    or ``[TIEUP] treadle = shafts`` with ``[TREADLING] pick = treadle(s)``. Section and key names
    are case-insensitive; ``;`` starts a comment; other sections are ignored.

    Raises
    ------
    WeaveError
        One line naming the file and, where there is one, the line number.

    Examples
    --------
    >>> from pathlib import Path
    >>> p = Path(getfixture("tmp_path")) / "plain.wif"
    >>> _ = p.write_text("[WIF]\\nVersion=1.1\\n[WEAVING]\\nShafts=2\\nTreadles=2\\n[WARP]\\nThreads=2\\n"
    ...                  "[WEFT]\\nThreads=2\\n[THREADING]\\n1=1\\n2=2\\n[TIEUP]\\n1=1\\n2=2\\n"
    ...                  "[TREADLING]\\n1=1\\n2=2\\n")
    >>> read_wif(p).tolist()
    [[1, 0], [0, 1]]
    """
    wif = _Wif(Path(path))
    shafts = wif.integer("weaving", "shafts")
    if shafts is None:
        raise wif.error(wif.header_line["weaving"], "[WEAVING] has no Shafts= entry")
    rising = wif.boolean("weaving", "rising shed", True)
    n_warp = wif.integer("warp", "threads") if wif.has("warp") else None
    n_weft = wif.integer("weft", "threads") if wif.has("weft") else None
    threading = wif.lists("threading", "thread", n_warp, "shaft", shafts, "[WEAVING] Shafts")

    if wif.has("liftplan"):
        lifts = wif.lists("liftplan", "pick", n_weft, "shaft", shafts, "[WEAVING] Shafts")
        picks = {p: items for p, (items, _) in lifts.items()}
    elif wif.has("tieup") or wif.has("treadling"):
        treadles = wif.integer("weaving", "treadles")
        if treadles is None:
            raise wif.error(wif.header_line["weaving"], "[WEAVING] has no Treadles= entry (needed for [TIEUP])")
        tieup = wif.lists("tieup", "treadle", treadles, "shaft", shafts, "[WEAVING] Shafts")
        treadling = wif.lists("treadling", "pick", n_weft, "treadle", treadles, "[WEAVING] Treadles")
        picks = {p: set().union(*(tieup.get(t, (set(), 0))[0] for t in items))
                 for p, (items, _) in treadling.items()}
    else:
        raise wif.error(None, "no [LIFTPLAN] and no [TIEUP] + [TREADLING] sections (needed for the drawdown)")

    n_warp = n_warp or max(threading, default=0)
    n_weft = n_weft or max(picks, default=0)
    if n_warp == 0 or n_weft == 0:
        raise wif.error(None, "the drawdown is empty (no threaded warp thread or no pick)")
    every = set(range(1, shafts + 1))
    matrix = np.zeros((n_warp, n_weft), dtype=np.int8)
    for pick in range(1, n_weft + 1):
        listed = picks.get(pick, set())
        raised = listed if rising else every - listed
        for thread, (on, _) in threading.items():
            if on & raised:
                matrix[thread - 1, pick - 1] = 1
    return matrix


def weave_from_wif(path: str | Path, **params: Any) -> Weave:
    """A :class:`Weave` of a WIF file's drawdown (:func:`read_wif`); ``params`` are the other fields.

    A drawdown that is not a valid weave (a thread that never interlaces) is a :class:`WeaveError`
    naming the file; rows and columns count from 0 (row ``j`` = warp thread ``j + 1``).
    """
    matrix = read_wif(path)
    try:
        return Weave(matrix, **params)
    except WeaveError as exc:
        raise WeaveError(f"{Path(path).name}: {exc} (row j = warp thread j + 1, column i = pick i + 1)") from None
