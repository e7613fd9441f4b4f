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

Mesh layout (:mod:`simulate.geometry.mesh`; the contract with :mod:`simulate.raytrace.scene`)
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
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import CubicSpline

__all__ = [
    "DEFAULT_CRIMP",
    "DEFAULT_HEIGHT_UM",
    "DEFAULT_POINTS_PER_SPAN",
    "DEFAULT_SIDES",
    "DEFAULT_SPACING_UM",
    "DEFAULT_WIDTH_UM",
    "MAX_TRIANGLES",
    "MAX_WEAVE_CELLS",
    "PRESETS",
    "Weave",
    "WeaveError",
    "preset",
]

# The shipped red-cotton weave (simulate/configs/red-cotton.toml): the defaults of a config
# without these fields.
DEFAULT_SPACING_UM = 300.0
DEFAULT_WIDTH_UM = 250.0
DEFAULT_HEIGHT_UM = 100.0
DEFAULT_CRIMP = 1.0
DEFAULT_POINTS_PER_SPAN = 16
DEFAULT_SIDES = 48

#: Bound on the micro-element's mesh (:func:`simulate.geometry.mesh.mesh`): a weave whose mesh would
#: have more triangles is refused when the :class:`Weave` is made, before anything is allocated.
#: The mesh has ``4 x sides x points_per_span x n_warp x n_weft`` triangles (two per quad, every
#: crossing on a warp and on a weft); the bound keeps the mesh's peak memory, and about as much again
#: for the tracer's trimesh/Embree copy, near a quarter GiB (docs/physics.md 6, "Size bounds").
MAX_TRIANGLES = 2_000_000
#: Bound on the weave matrix (warp threads x picks): the largest that still meshes within
#: :data:`MAX_TRIANGLES` with the coarsest mesh (``sides = 3``, ``points_per_span = 1``); a WIF
#: drawdown is checked against it before its matrix is allocated.
MAX_WEAVE_CELLS = MAX_TRIANGLES // 12
#: Bytes per triangle at the peak of :func:`simulate.geometry.mesh.mesh` (see :data:`MAX_TRIANGLES`).
MESH_BYTES_PER_TRIANGLE = 136


def triangle_count(n_warp: int, n_weft: int, points_per_span: int, sides: int) -> int:
    """Triangles of the mesh of such a weave: ``4 sides points_per_span n_warp n_weft`` (exact).

    Examples
    --------
    >>> triangle_count(2, 2, 4, 8)        # 4 yarns x 2 x (4 x 2) x 8
    512
    """
    return 4 * int(sides) * int(points_per_span) * int(n_warp) * int(n_weft)


def check_mesh_size(n_warp: int, n_weft: int, points_per_span: int, sides: int) -> None:
    """Refuse a weave whose mesh exceeds :data:`MAX_TRIANGLES` (a :class:`WeaveError` with the figures)."""
    count = triangle_count(n_warp, n_weft, points_per_span, sides)
    if count > MAX_TRIANGLES:
        gib = count * MESH_BYTES_PER_TRIANGLE / 2**30
        raise WeaveError(
            f"weave mesh too large: {n_warp} x {n_weft} yarns with points_per_span = {points_per_span} and "
            f"sides = {sides} give {count:,} triangles (about {gib:,.1f} GiB to build); the bound is "
            f"{MAX_TRIANGLES:,} (about {MAX_TRIANGLES * MESH_BYTES_PER_TRIANGLE / 2**30:.2f} GiB): lower "
            f"points_per_span or sides, or use a smaller repeat")


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
    """A bad weave (matrix, dimensions, WIF file, export path).

    Its message is one line naming the row, column, line or field.
    """


# ------------------------------------------------------------------------------------------
# the weave


def _check_cells(n_warp: int, n_weft: int) -> None:
    if n_warp * n_weft > MAX_WEAVE_CELLS:
        raise WeaveError(f"weave matrix: {n_warp} x {n_weft} = {n_warp * n_weft:,} crossings; at most "
                         f"{MAX_WEAVE_CELLS:,} (the largest repeat whose coarsest mesh, sides = 3 and "
                         f"points_per_span = 1, stays within {MAX_TRIANGLES:,} triangles)")


def _matrix(value: Any) -> np.ndarray:
    """Validate a 0/1 matrix given as nested lists or an array; an int8 array."""
    if isinstance(value, np.ndarray):
        if value.ndim != 2:
            raise WeaveError(f"weave matrix: must be 2-D (rows = warp yarns), got {value.ndim}-D")
        _check_cells(value.shape[0], value.shape[1])
        rows = [list(r) for r in value]
    else:
        if not isinstance(value, (list, tuple)) or not all(isinstance(r, (list, tuple, np.ndarray)) for r in value):
            raise WeaveError("weave matrix: must be a list of rows (one per warp yarn) of 0/1 entries")
        rows = [list(r) for r in value]
    if not rows or not rows[0]:
        raise WeaveError("weave matrix: is empty; it needs at least 2 rows and 2 columns")
    _check_cells(len(rows), len(rows[0]))
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

    The mesh these imply (``4 sides points_per_span n_warp n_weft`` triangles) must stay within
    :data:`MAX_TRIANGLES` (2 million, about 0.27 GiB to build): a larger weave is refused here,
    before anything is allocated.

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
        check_mesh_size(self.n_warp, self.n_weft, self.points_per_span, self.sides)

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
        """The yarn's centre height ``z_c(s)``.

        A periodic cubic spline (period ``L``) through its control points; it extrapolates periodically,
        so it may be evaluated on ``[0, L]``.
        """
        s, z = self.control_points(yarn)
        return CubicSpline(s, z, bc_type="periodic")


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
