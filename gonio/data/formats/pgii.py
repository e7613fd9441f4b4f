"""pgII text files (PAB goniophotometer II): one incidence per file, several files per dataset.

A file is ``#`` header lines, then data lines ``theta phi value...`` (whitespace separated)::

    #sample_name "felt"
    #intheta 30            (also #incident_angle; degrees)
    #inphi 0               (optional, degrees)
    #format: theta phi BSDF        (or DSF, or [uA]: raw detector current)
    #lambda=450 550 650    (optional: one value column per wavelength, nm)
    0 0 0.123
    ...

``BSDF`` values are ``f_r`` (1/sr); ``DSF`` (differential scattering function) values are
``f_r cos theta_o``; ``[uA]`` values are raw detector currents, which make a *relative* dataset
(``"relative": true``) unless a scale (``f_r`` per uA) is given. Without ``#lambda=`` the single
value column is photometric (channel ``Y``). ``theta > 90`` is the other half of the plane:
``theta -> 180 - theta``, ``phi -> phi + 180`` (the instrument scans through the normal). Other
``#`` lines are kept in the provenance. ``beta = pi f_r``.

References
----------
PAB Advanced Technologies, pgII goniophotometer data export (``#format`` header convention).
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from gonio.data.formats.errors import FormatError

__all__ = ["PgiiFile", "parse_pgii", "read_pgii", "pgii_dataset"]

UNITS = ("BSDF", "DSF", "[uA]")
MAX_BYTES = 64 * 1024 * 1024


class PgiiFile:
    """One parsed pgII file: its incidence, unit, wavelengths (or None) and value rows."""

    def __init__(self, path: str, sample: str, theta_i: float, phi_i: float, unit: str,
                 wavelengths_nm: list[float] | None, theta_o: np.ndarray, phi_o: np.ndarray,
                 values: np.ndarray, header: dict[str, str]):
        self.path = path
        self.sample = sample
        self.theta_i = theta_i
        self.phi_i = phi_i
        self.unit = unit
        self.wavelengths_nm = wavelengths_nm
        self.theta_o = theta_o
        self.phi_o = phi_o
        self.values = values
        self.header = header


def read_pgii(path: str | os.PathLike) -> PgiiFile:
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FormatError(f"cannot be read ({exc.strerror})", file=path) from None
    if len(data) > MAX_BYTES:
        raise FormatError(f"file is {len(data)} bytes; a pgII file of one incidence is far "
                          "smaller", file=path)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        try:
            text = data.decode("latin-1")
        except UnicodeDecodeError:
            raise FormatError(f"not text ({exc.reason})", file=path, offset=exc.start) from None
    return parse_pgii(text, str(path))


def _number(token: str, what: str, path: str, line: int) -> float:
    try:
        value = float(token)
    except ValueError:
        raise FormatError(f"{what} {token!r} is not a number", file=path, line=line) from None
    if not math.isfinite(value):
        raise FormatError(f"{what} {token!r} is not a finite number", file=path, line=line)
    return value


def parse_pgii(text: str, path: str = "<pgII>") -> PgiiFile:
    """Parse the text of a pgII file; raise :class:`FormatError` naming the line."""
    header: dict[str, str] = {}
    sample, theta_i, phi_i, unit, wavelengths = "", None, 0.0, None, None
    rows: list[list[float]] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            body = line[1:].strip()
            m = re.match(r"([A-Za-z_]+)\s*[:=]?\s*(.*)$", body)
            if not m:
                continue
            key, value = m.group(1).lower(), m.group(2).strip()
            header[key] = value
            if key == "sample_name":
                sample = value.strip('"')
            elif key in ("intheta", "incident_angle"):
                theta_i = _number(value.split()[0] if value else "", f"#{key}", path, number)
                if not 0 <= theta_i <= 90:
                    raise FormatError(f"#{key} {theta_i:g} must be in [0, 90] degrees", file=path,
                                      line=number)
            elif key == "inphi":
                phi_i = _number(value.split()[0] if value else "", "#inphi", path, number) % 360.0
            elif key == "format":
                cols = value.split()
                if len(cols) != 3 or cols[0].lower() != "theta" or cols[1].lower() != "phi" \
                        or cols[2] not in UNITS:
                    raise FormatError(f"#format is {value!r}", file=path, line=number,
                                      hint="expected '#format: theta phi DSF' (or BSDF or [uA])")
                unit = cols[2]
            elif key == "lambda":
                wavelengths = [_number(t, "#lambda wavelength", path, number)
                               for t in value.replace(",", " ").split()]
                if not wavelengths or any(not 200 <= w <= 2500 for w in wavelengths) \
                        or len(set(wavelengths)) != len(wavelengths):
                    raise FormatError("#lambda= must list distinct wavelengths in 200..2500 nm",
                                      file=path, line=number)
            continue
        tokens = line.replace(",", " ").split()
        n_values = len(wavelengths) if wavelengths else 1
        if len(tokens) != 2 + n_values:
            raise FormatError(f"{len(tokens)} columns, expected {2 + n_values} (theta phi and "
                              f"{n_values} value{'s' if n_values > 1 else ''})", file=path,
                              line=number)
        theta = _number(tokens[0], "theta", path, number)
        phi = _number(tokens[1], "phi", path, number)
        if not 0 <= theta <= 180:
            raise FormatError(f"theta {theta:g} must be in [0, 180] degrees", file=path,
                              line=number)
        values = [_number(t, "value", path, number) for t in tokens[2:]]
        rows.append([theta, phi] + values)
    if theta_i is None:
        raise FormatError("no #intheta (or #incident_angle) header line", file=path,
                          hint="each pgII file holds one incidence angle, named in its header")
    if unit is None:
        raise FormatError("no '#format: theta phi UNIT' header line", file=path)
    if not rows:
        raise FormatError("no data lines", file=path)
    arr = np.asarray(rows, dtype=float)
    beyond = arr[:, 0] > 90.0          # the other half of the scan plane
    theta_o = np.where(beyond, 180.0 - arr[:, 0], arr[:, 0])
    phi_o = np.mod(np.where(beyond, arr[:, 1] + 180.0, arr[:, 1]), 360.0)
    return PgiiFile(path, sample, float(theta_i), float(phi_i), unit, wavelengths, theta_o,
                    phi_o, arr[:, 2:], header)


def pgii_dataset(files: Sequence[PgiiFile], *, scale: float | None = None):
    """One dataset from several pgII files (one incidence each).

    ``[uA]`` files need ``scale`` (``f_r`` per uA) for absolute values; without it the dataset
    is relative. All files must share the unit and the wavelengths.
    """
    from gonio.data.dataset import make_dataset, new_meta

    if not files:
        raise FormatError("no pgII files given")
    first = files[0]
    for f in files[1:]:
        if f.unit != first.unit or f.wavelengths_nm != first.wavelengths_nm:
            raise FormatError(f"unit {f.unit} / wavelengths {f.wavelengths_nm} differ from "
                              f"{first.path}'s ({first.unit} / {first.wavelengths_nm})", file=f.path,
                              hint="one dataset needs files of the same format")
    relative = first.unit == "[uA]" and scale is None
    parts = []
    for f in files:
        cos_o = np.cos(np.radians(f.theta_o))
        values = f.values.copy()
        if f.unit == "DSF":
            with np.errstate(divide="ignore", invalid="ignore"):
                values = values / cos_o[:, None]
            keep = cos_o > 1e-9
        else:
            keep = np.ones(cos_o.size, dtype=bool)
        if f.unit == "[uA]" and scale is not None:
            values = values * scale
        beta = values if relative else np.pi * values
        bands: list = list(f.wavelengths_nm) if f.wavelengths_nm else ["Y"]
        for k, band in enumerate(bands):
            part = pd.DataFrame({"theta_i": f.theta_i, "phi_i": f.phi_i,
                                 "theta_o": f.theta_o[keep], "phi_o": f.phi_o[keep]})
            part["wavelength_nm" if f.wavelengths_nm else "channel"] = band
            part["beta"] = beta[keep, k]
            part["u_beta"] = 0.0
            part["n"] = 1
            parts.append(part)
    meta = new_meta("measured", {"name": first.sample or Path(first.path).stem},
                    {"name": "PAB pgII goniophotometer", "format": "pgii", "unit": first.unit},
                    {"source_files": [Path(f.path).name for f in files],
                     "headers": {Path(f.path).name: f.header for f in files},
                     **({"scale_fr_per_uA": scale} if scale is not None else {})},
                    relative=relative)
    if not first.wavelengths_nm:
        meta["colour_space"] = "linear sRGB"
    return make_dataset(pd.concat(parts, ignore_index=True), meta, source=first.path)
