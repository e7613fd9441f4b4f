"""Validation of a radiance-coefficient dataset's two files: the table and the metadata.

The checks :func:`gonio.data.dataset.read_dataset`, :func:`~gonio.data.dataset.make_dataset` and
:func:`~gonio.data.dataset.write_dataset` share, apart from the `Dataset` they guard. Each failure is a
`DatasetError` naming the file, the row (the line in the file, the header being line 1), the column
and the problem. :func:`canonical_phi` holds the storage convention of the azimuths (see
:mod:`gonio.data.dataset`).
"""

from __future__ import annotations

import errno
import math
import os
import stat
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from gonio.data.schema import (
    ANGLE_TOL_DEG,
    BETA_MAX,
    CHANNELS,
    COLUMNS,
    CSV_NAME,
    GEOMETRY,
    KINDS,
    META_MAX_DEPTH,
    META_NAME,
    N_MAX,
    RGB_COLUMNS,
    SCHEMA,
    U_BETA_MAX_RATIO,
    WAVELENGTH_RANGE_NM,
    DatasetError,
)

__all__ = ["canonical_phi", "check_colour_space", "file_kind", "require_regular_file", "validate_meta", "validate_table"]


def canonical_phi(table: pd.DataFrame) -> pd.DataFrame:
    """Phi in [0, 360); ``phi_o`` of the normal direction set to ``phi_i + 180`` (see module doc)."""
    table = table.copy()
    for col in ("phi_i", "phi_o"):
        phi = np.mod(table[col].to_numpy(dtype=float), 360.0)
        phi[np.isclose(phi, 360.0, atol=ANGLE_TOL_DEG)] = 0.0
        table[col] = phi
    normal_o = np.abs(table["theta_o"].to_numpy(dtype=float)) < ANGLE_TOL_DEG
    if normal_o.any():
        table.loc[normal_o, "phi_o"] = np.mod(table.loc[normal_o, "phi_i"] + 180.0, 360.0)
    return table


def validate_table(table: pd.DataFrame, file: str | None, *, line_offset: int = 2) -> pd.DataFrame:
    """Check columns, numbers, ranges and duplicates; return a float/int typed, sorted copy.

    ``line_offset`` maps a 0-based data index to the row number users see (2 = file line, header
    on line 1).
    """
    if table.shape[0] == 0:
        raise DatasetError("no data rows", file=file,
                           hint="a dataset needs at least one (geometry, wavelength) row")
    columns = [str(c).strip() for c in table.columns]
    rgb = "channel" in columns and "wavelength_nm" not in columns
    expected = RGB_COLUMNS if rgb else COLUMNS
    band = expected[4]
    missing = [c for c in expected if c not in columns]
    if missing:
        raise DatasetError(f"missing column(s) {', '.join(missing)}", file=file, row=1,
                           hint=f"the header must be {','.join(COLUMNS)} (or, for an RGB "
                                f"dataset, {','.join(RGB_COLUMNS)})")
    extra = [c for c in columns if c not in expected]
    if extra or tuple(columns) != expected:
        raise DatasetError(
            f"columns are {','.join(columns)}" + (f" (unknown: {', '.join(extra)})" if extra else ""),
            file=file, row=1, hint=f"the header must be exactly {','.join(expected)} in this order")
    table = table.copy()
    table.columns = columns
    out: dict[str, Any] = {}
    if rgb:
        channel = table["channel"].astype(str).str.strip().to_numpy()
        bad = ~np.isin(channel, CHANNELS)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise DatasetError(f"value {str(table['channel'].iloc[i])!r} is not a channel",
                               file=file, row=i + line_offset, column="channel",
                               hint=f"a channel is one of {', '.join(CHANNELS)}")
        out["channel"] = channel.astype(object)
    for col in expected:
        if col == "channel":
            continue
        raw = table[col]
        values = pd.to_numeric(raw, errors="coerce").to_numpy(dtype=float)
        bad = ~np.isfinite(values)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            shown = raw.iloc[i]
            shown = "empty" if (shown is None or (isinstance(shown, float) and math.isnan(shown))
                                or str(shown).strip() == "") else repr(str(shown))
            raise DatasetError(f"value {shown} is not a finite number", file=file,
                               row=i + line_offset, column=col)
        out[col] = values
    checks = [
        ("theta_i", lambda v: (v >= 0) & (v <= 90), "must be in [0, 90] degrees"),
        ("theta_o", lambda v: (v >= 0) & (v <= 90), "must be in [0, 90] degrees"),
        ("phi_i", lambda v: (v >= 0) & (v < 360), "must be in [0, 360) degrees"),
        ("phi_o", lambda v: (v >= 0) & (v < 360), "must be in [0, 360) degrees"),
        ("wavelength_nm", lambda v: (v >= WAVELENGTH_RANGE_NM[0]) & (v <= WAVELENGTH_RANGE_NM[1]),
         f"must be in [{WAVELENGTH_RANGE_NM[0]:g}, {WAVELENGTH_RANGE_NM[1]:g}] nm"),
        ("beta", lambda v: np.abs(v) <= BETA_MAX,
         f"is not a plausible radiance coefficient (|beta| must be <= {BETA_MAX:g})"),
        ("u_beta", lambda v: v >= 0, "must be >= 0"),
        ("u_beta", lambda v: v <= U_BETA_MAX_RATIO * max(float(np.max(np.abs(out["beta"]))), 1.0),
         f"is not a plausible standard uncertainty: it exceeds {U_BETA_MAX_RATIO:g} times the "
         "largest |beta| of the file (or 1); leave out a point whose value is unknown"),
        ("n", lambda v: (v >= 1) & (v == np.round(v)), "must be a whole number >= 1"),
        ("n", lambda v: v <= N_MAX, f"is out of range (a count must be <= 2^53 = {N_MAX:d})"),
    ]
    for col, ok, what in checks:
        if col not in out:
            continue
        good = ok(out[col])
        if not good.all():
            i = int(np.flatnonzero(~good)[0])
            raise DatasetError(f"value {out[col][i]:g} {what}", file=file, row=i + line_offset,
                               column=col)
    frame = pd.DataFrame(out, columns=list(expected))
    frame["n"] = frame["n"].astype(np.int64)
    frame = canonical_phi(frame)
    key = frame[list(GEOMETRY)].round(6)
    key[band] = frame[band]
    dup = key.duplicated(keep=False).to_numpy()
    if dup.any():
        rows = np.flatnonzero(dup)
        first = key.iloc[rows[0]]
        same = rows[(key.iloc[rows] == first).all(axis=1).to_numpy()]
        geometry = ", ".join(f"{c}={first[c]}" if c == "channel" else f"{c}={first[c]:g}"
                             for c in key.columns)
        raise DatasetError(f"duplicate geometry and {'channel' if rgb else 'wavelength'} "
                           f"({geometry}), also on row "
                           f"{int(same[1]) + line_offset}", file=file,
                           row=int(same[0]) + line_offset,
                           hint="each (geometry, wavelength) must appear once")
    if rgb:
        frame["_order"] = [CHANNELS.index(c) for c in frame["channel"]]
        frame = frame.sort_values(list(GEOMETRY) + ["_order"], kind="mergesort")
        frame = frame.drop(columns="_order")
    else:
        frame = frame.sort_values(list(GEOMETRY) + ["wavelength_nm"], kind="mergesort")
    return frame.reset_index(drop=True)


def _meta_depth_ok(meta: Any) -> bool:
    """True when ``meta`` nests no deeper than `META_MAX_DEPTH` (iterative: no recursion)."""
    stack = [(meta, 1)]
    while stack:
        value, depth = stack.pop()
        if isinstance(value, (dict, list)):
            if depth > META_MAX_DEPTH:
                return False
            children = value.values() if isinstance(value, dict) else value
            stack.extend((child, depth + 1) for child in children)
    return True


def _type_name(value: Any) -> str:
    return {dict: "an object", list: "a list", str: "a string", bool: "true/false",
            type(None): "null", int: "a number", float: "a number"}.get(type(value),
                                                                        type(value).__name__)


def validate_meta(meta: Any, file: str | None) -> dict:  # noqa: C901
    """Check the keys of ``meta.json`` that the format defines (types, schema, kind); return ``meta``."""
    if not isinstance(meta, dict):
        raise DatasetError(f"must hold a JSON object, not {_type_name(meta)}", file=file)
    if not _meta_depth_ok(meta):
        raise DatasetError(f"nested deeper than {META_MAX_DEPTH} levels", file=file,
                           hint="meta.json holds a few levels of keys; regenerate it")
    schema = meta.get("schema")
    if schema is None:
        raise DatasetError("missing key 'schema'", file=file, hint=f"expected \"{SCHEMA}\"")
    if schema != SCHEMA:
        raise DatasetError(f"unknown schema {schema!r}", file=file,
                           hint=f"this version reads \"{SCHEMA}\"")
    kind = meta.get("kind")
    if kind not in KINDS:
        raise DatasetError(f"key 'kind' is {kind!r}", file=file,
                           hint="it must be \"measured\" or \"simulated\"")

    def expect(path: str, value: Any, types: tuple, what: str) -> None:
        if not isinstance(value, types) or (bool not in types and isinstance(value, bool)):
            raise DatasetError(f"key '{path}' must be {what}, not {_type_name(value)}", file=file,
                               hint="fix or regenerate meta.json")

    for key in ("sample", "instrument", "model", "software", "provenance", "files"):
        if key in meta:
            expect(key, meta[key], (dict,), "an object")
    if "name" in meta.get("sample", {}):
        expect("sample.name", meta["sample"]["name"], (str,), "a string")
    if "created" in meta:
        expect("created", meta["created"], (str,), "an ISO-8601 date string")
    if "wavelengths_nm" in meta:
        expect("wavelengths_nm", meta["wavelengths_nm"], (list,), "a list of numbers")
        for j, w in enumerate(meta["wavelengths_nm"]):
            expect(f"wavelengths_nm[{j}]", w, (int, float), "a number")
    if "channels" in meta:
        expect("channels", meta["channels"], (list,), "a list of channel names")
        for j, c in enumerate(meta["channels"]):
            if c not in CHANNELS:
                raise DatasetError(f"key 'channels[{j}]' is {c!r}; a channel is one of "
                                   f"{', '.join(CHANNELS)}", file=file)
    if "colour_space" in meta:
        expect("colour_space", meta["colour_space"], (str,), "a string such as \"linear sRGB\"")
        check_colour_space(meta["colour_space"], file)
    if "relative" in meta:
        expect("relative", meta["relative"], (bool,), "true or false")
    files = meta.get("files", {})
    if CSV_NAME in files:
        expect(f"files.{CSV_NAME}", files[CSV_NAME], (dict,), "an object")
        if "sha256" in files[CSV_NAME]:
            expect(f"files.{CSV_NAME}.sha256", files[CSV_NAME]["sha256"], (str,),
                   "a hexadecimal string")
    provenance = meta.get("provenance", {})
    if "complete" in meta:
        expect("complete", meta["complete"], (bool,), "true or false")
    if "complete" in provenance:
        expect("provenance.complete", provenance["complete"], (bool,), "true or false")
    for key in ("points_planned", "points_measured"):
        if key in provenance:
            expect(f"provenance.{key}", provenance[key], (int,), "a whole number")
            if provenance[key] < 0:
                raise DatasetError(f"key 'provenance.{key}' is {provenance[key]}; it must be >= 0",
                                   file=file)
    return meta


def check_colour_space(name: str, file: str | None) -> None:
    """Accept ``"linear NAME"`` with NAME a colour-science RGB colour space (e.g. sRGB)."""
    import colour

    if not name.startswith("linear "):
        raise DatasetError(f"key 'colour_space' is {name!r}: only linear colour spaces are "
                           "supported", file=file,
                           hint="name it \"linear sRGB\" (or \"linear NAME\" with NAME a "
                                "colour-science RGB colour space) and store linear values")
    if name[len("linear "):] not in colour.RGB_COLOURSPACES:
        raise DatasetError(f"key 'colour_space' names an unknown colour space {name!r}",
                           file=file, hint="use \"linear sRGB\" or \"linear NAME\" with NAME a key "
                                           "of colour.RGB_COLOURSPACES")


def require_regular_file(path: Path) -> None:
    """Refuse anything but a readable regular file, saying what it is (a FIFO would block)."""
    hint = f"a dataset directory holds the regular files {CSV_NAME} and {META_NAME}"
    try:
        st = os.stat(path)
    except OSError as exc:
        if os.path.islink(path):
            what = ("is a symbolic link that loops" if exc.errno == errno.ELOOP
                    else f"is a symbolic link to a missing target ({os.readlink(path)})")
            raise DatasetError(what, file=path, hint=hint) from None
        if exc.errno == errno.ENOENT:
            raise DatasetError("file is missing", file=path, hint=hint) from None
        raise DatasetError(f"cannot be opened ({exc.strerror})", file=path, hint=hint) from None
    if not stat.S_ISREG(st.st_mode):
        raise DatasetError(f"is {file_kind(st.st_mode)}, not a regular file", file=path,
                           hint=hint)


def file_kind(mode: int) -> str:
    """What a file of mode ``mode`` is, in words (``a FIFO (named pipe)``)."""
    kinds = [(stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
             (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISREG, "a regular file")]
    return next((name for test, name in kinds if test(mode)), "a special file")
