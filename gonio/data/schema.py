"""The dataset format's constants and its error type: the leaf of :mod:`gonio.data`.

Everything here is plain data (names, columns, limits) and :class:`DatasetError`; the modules
that read, write, interpolate or convert datasets import it, and it imports nothing of theirs,
so :mod:`gonio.data.dataset` and :mod:`gonio.data.interpolate` need not import each other.
The meaning of each name is in docs/dataset.md.
"""

from __future__ import annotations

import os

__all__ = ["SCHEMA", "COLUMNS", "RGB_COLUMNS", "GEOMETRY", "CHANNELS", "DEFAULT_COLOUR_SPACE",
           "KINDS", "CSV_NAME", "META_NAME", "ANGLE_TOL_DEG", "WAVELENGTH_RANGE_NM", "N_MAX",
           "BETA_MAX", "U_BETA_MAX_RATIO", "META_MAX_DEPTH", "DatasetError"]

SCHEMA = "radiance-dataset/1"
COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm", "beta", "u_beta", "n")
#: Columns of an RGB (or photometric) dataset: ``channel`` in place of ``wavelength_nm``.
RGB_COLUMNS = ("theta_i", "phi_i", "theta_o", "phi_o", "channel", "beta", "u_beta", "n")
GEOMETRY = COLUMNS[:4]
#: Channels an RGB dataset may carry (Y: a photometric measurement), in their canonical order.
CHANNELS = ("R", "G", "B", "Y")
#: Colour space of an RGB dataset whose meta.json names none.
DEFAULT_COLOUR_SPACE = "linear sRGB"
KINDS = ("measured", "simulated")
CSV_NAME = "radiance.csv"
META_NAME = "meta.json"

#: Tolerance (degrees) under which two angles are the same geometry.
ANGLE_TOL_DEG = 1e-6
#: Wavelengths accepted (nm): the instrument's monochromator spans 380..780; simulations may go wider.
WAVELENGTH_RANGE_NM = (200.0, 2500.0)
#: Largest ``n`` accepted: 2**53, the largest count a CSV float holds exactly (a photon budget of
#: 9e15 is far beyond any simulation; larger values would also overflow on conversion to int64).
N_MAX = 2 ** 53
#: Largest ``|beta|`` accepted. A radiance factor of real surfaces is of order 1 (a mirror seen
#: through a milliradian aperture is ~1e6, a simulation's raw scale may be larger); 1e100 leaves
#: every use open while keeping squares and sums over a dataset finite (1e308 would overflow).
BETA_MAX = 1e100
#: ``u_beta`` may be at most this many times the largest ``|beta|`` of the file (or of 1, for a
#: file whose values are all ~0): an uncertainty ten times the largest value says the value is
#: unknown, so such a row must be left out, not stored with a made-up number.
U_BETA_MAX_RATIO = 10.0
#: Deepest nesting accepted in meta.json (the contract's keys are 3 levels deep; free-form
#: provenance may go deeper, but not 10^5 levels, which would exhaust the interpreter's stack).
META_MAX_DEPTH = 32


class DatasetError(ValueError):
    """A dataset (or a request to it) is invalid. The message names file, row, column, problem."""

    def __init__(self, problem: str, *, file: str | os.PathLike | None = None,
                 row: int | None = None, column: str | None = None, hint: str | None = None):
        self.problem = problem
        self.file = None if file is None else str(file)
        self.row = row
        self.column = column
        self.hint = hint
        where = []
        if self.file is not None:
            where.append(self.file)
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column '{column}'")
        message = (": ".join([", ".join(where), problem]) if where else problem)
        if hint:
            message += f" ({hint})"
        super().__init__(message)
