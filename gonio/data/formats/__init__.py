"""Importers of other formats into radiance-coefficient datasets (``gonio import FORMAT FILE``).

``rgl-bsdf``
    RGL ``.bsdf`` tensor files (Dupuy & Jakob 2018), RGB or spectral: :mod:`.rgl_bsdf`.
``pgii``
    PAB pgII text files, one incidence per file: :mod:`.pgii`.
``merl``
    MERL binary BRDF tables (isotropic RGB): :mod:`.merl` (reader and writer).

Every malformed file raises :class:`FormatError` naming the file, the byte offset or line, and
the problem. Every importer reads through :class:`~gonio.data.formats.errors.RegularFile`: a FIFO,
a device (``/dev/zero``) or a directory is refused, and so is a file larger than the format's
bound (``.bsdf`` 128 MiB, MERL its fixed 34 992 012 bytes, pgII 32 MiB), from its size, before
anything is read; a ``.bsdf``'s declared shapes are checked against the file before its tables
are read.

Near-grazing incidence (one rule for every format, :data:`GRAZING_DEG`): rows with ``theta_i >=
89`` degrees are dropped at import, with a note, unless ``keep_grazing`` (``gonio import
--keep-grazing``). The RGL files end at ``theta_i = 89.99999567`` degrees: there the projected
area ``cos theta_i`` vanishes, the stored tables are extrapolations of the warp rather than
measurements, and the values (``beta`` up to several times the rest) would dominate every plot
and residual of a comparison. The dropped incidences are listed in the provenance
(``grazing_dropped``).
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import pandas as pd

from gonio.data.formats.errors import FormatError

__all__ = ["FORMATS", "GRAZING_DEG", "FormatError", "import_files", "import_notes"]

FORMATS = ("rgl-bsdf", "pgii", "merl")
#: Incidence from which rows are dropped at import unless asked to keep them (see above).
GRAZING_DEG = 89.0


def import_files(fmt: str, paths: Sequence[str | os.PathLike],
                 geometries: pd.DataFrame | None = None, *, scale: float | None = None,
                 white: str | os.PathLike | None = None, white_reflectance: float = 0.99,
                 keep_grazing: bool = False):
    """Read ``paths`` of format ``fmt`` into one dataset (at ``geometries`` where applicable).

    Rows at ``theta_i >= GRAZING_DEG`` are dropped unless ``keep_grazing`` (module docstring).
    """
    dataset = _import(fmt, paths, geometries, scale=scale, white=white,
                      white_reflectance=white_reflectance)
    return dataset if keep_grazing else _drop_grazing(dataset, paths)


def _drop_grazing(dataset, paths):
    from gonio.data.dataset import make_dataset

    table = dataset.table
    grazing = table["theta_i"].to_numpy(dtype=float) >= GRAZING_DEG
    if not grazing.any():
        return dataset
    if grazing.all():
        raise FormatError(f"every geometry is at incidence >= {GRAZING_DEG:g} deg (near grazing, "
                          "dropped by default)", file=paths[0],
                          hint="add --keep-grazing to import them")
    meta = dict(dataset.meta)
    meta["provenance"] = {**meta.get("provenance", {}), "grazing_dropped": {
        "theta_i_min_deg": GRAZING_DEG, "rows": int(grazing.sum()),
        "theta_i_deg": sorted({float(t) for t in table["theta_i"][grazing]})}}
    return make_dataset(table[~grazing].reset_index(drop=True), meta, source=str(paths[0]))


def import_notes(dataset) -> list[str]:
    """What an import changed or found, one line each (``gonio import`` prints them)."""
    provenance = dataset.meta.get("provenance", {})
    notes = []
    grazing = provenance.get("grazing_dropped")
    if grazing:
        angles = ", ".join(f"{t:.8g}" for t in grazing["theta_i_deg"])
        notes.append(f"dropped {grazing['rows']} rows at near-grazing incidence (theta_i "
                     f"{angles} deg >= {grazing['theta_i_min_deg']:g}); --keep-grazing keeps them")
    negative = provenance.get("negative_values")
    if negative:
        per = "; ".join(f"{band}: {v['stored']} of {v['of']} stored values, {v['rows']} rows of "
                        "the dataset" for band, v in negative.items())
        notes.append(f"negative values kept as stored (measurement noise around zero): {per}")
    return notes


def _import(fmt: str, paths: Sequence[str | os.PathLike], geometries: pd.DataFrame | None, *,
            scale: float | None, white: str | os.PathLike | None, white_reflectance: float):
    if fmt not in FORMATS:
        raise FormatError(f"unknown format {fmt!r}", hint=f"use one of {', '.join(FORMATS)}")
    if fmt == "pgii":
        from gonio.data.formats.pgii import pgii_dataset, read_pgii

        if geometries is not None:
            raise FormatError("pgII files are measured at their own geometries; --plan "
                              "does not apply", hint="leave out --plan")
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
