"""Importers of other formats into radiance-coefficient datasets (``gonio import FORMAT FILE``).

``rgl-bsdf``
    RGL ``.bsdf`` tensor files (Dupuy & Jakob 2018), RGB or spectral: :mod:`.rgl_bsdf`.
``pgii``
    PAB pgII text files, one incidence per file: :mod:`.pgii`.
``merl``
    MERL binary BRDF tables (isotropic RGB): :mod:`.merl` (reader and writer).

Every malformed file raises :class:`FormatError` naming the file, the byte offset or line, and
the problem.
"""

from __future__ import annotations

import os
from typing import Sequence

import pandas as pd

from gonio.data.formats.errors import FormatError

__all__ = ["FORMATS", "FormatError", "import_files"]

FORMATS = ("rgl-bsdf", "pgii", "merl")


def import_files(fmt: str, paths: Sequence[str | os.PathLike],
                 geometries: pd.DataFrame | None = None, *, scale: float | None = None,
                 white: str | os.PathLike | None = None, white_reflectance: float = 0.99):
    """Read ``paths`` of format ``fmt`` into one dataset (at ``geometries`` where applicable)."""
    if fmt not in FORMATS:
        raise FormatError(f"unknown format {fmt!r}", hint=f"use one of {', '.join(FORMATS)}")
    if fmt == "pgii":
        from gonio.data.formats.pgii import pgii_dataset, read_pgii

        if geometries is not None:
            raise FormatError("pgII files are measured at their own geometries; --geometry "
                              "does not apply", hint="leave out --geometry")
        return pgii_dataset([read_pgii(p) for p in paths], scale=scale,
                            white=read_pgii(white) if white is not None else None,
                            white_reflectance=white_reflectance)
    if white is not None:
        raise FormatError("--white applies to pgII [uA] files only", hint="leave out --white")
    if len(paths) != 1:
        raise FormatError(f"format {fmt} takes one file, not {len(paths)}")
    if fmt == "rgl-bsdf":
        from gonio.data.formats.rgl_bsdf import read_rgl_bsdf

        return read_rgl_bsdf(paths[0]).to_dataset(geometries)
    from gonio.data.formats.merl import read_merl

    return read_merl(paths[0]).to_dataset(geometries)
