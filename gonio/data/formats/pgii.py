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
(``"relative": true``) unless a scale (``f_r`` per uA) or a white reference is given.

White reference: a ``[uA]`` pgII file of a diffuse white standard of known reflectance ``rho_w``
(taken as Lambertian, ``f_r = rho_w / pi``), measured with the same detector and source. The
detector reads ``I = K f_r E cos(theta_i)`` (a collimated beam on a tilted sample), so per band::

    f_r(sample) = (rho_w / pi) (I / cos theta_i) / <I_w / cos theta_w>

with ``<...>`` the mean over the reference's rows observed within 60 degrees of its normal (a
real standard departs from Lambert at grazing observation). Without ``#lambda=`` the single
value column is photometric (channel ``Y``). ``theta > 90`` is the other half of the plane:
``theta -> 180 - theta``, ``phi -> phi + 180`` (the instrument scans through the normal). Other
``#`` lines are kept in the provenance. ``beta = pi f_r``.

Negative values. A dark-subtracted detector reads values scattered around zero where there is no
signal (grazing or back-scatter directions), so a value slightly below zero is a measurement, not
an error, and is kept as stored; a value far below zero is not noise (a sign or column error) and
is refused. The rule, per file and value column (wavelength or ``Y``): a negative value is kept
when it is no further below zero than :data:`NEGATIVE_NOISE` (5 %) of the column's largest value
in that file, and refused otherwise, naming the file, the line and the bound; a column with
negative values and no value above zero is refused as well (nothing to compare the noise with).
Kept negatives are counted per band in ``provenance.negative_values`` (``stored`` of ``of`` values
of the files, ``rows`` of the dataset) and ``gonio import`` says so in a note, as for the RGL
``.bsdf`` files (docs/dataset.md).

References
----------
PAB Advanced Technologies, pgII goniophotometer data export (``#format`` header convention).
"""

from __future__ import annotations

import logging
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from gonio.data.formats.errors import FormatError, read_file_bytes

__all__ = ["NEGATIVE_NOISE", "PgiiFile", "parse_pgii", "read_pgii", "pgii_dataset", "white_reference_scale"]

log = logging.getLogger(__name__)

UNITS = ("BSDF", "DSF", "[uA]")
#: Largest pgII file read (checked from its size before reading): one incidence at 1 degree over
#: the hemisphere is 32 400 lines, about 13 MB with 40 wavelengths.
MAX_BYTES = 32 * 1024 * 1024
#: Most data lines of one file (a 0.25-degree hemisphere scan is 518 400).
MAX_ROWS = 600_000
#: A negative value is kept as noise around zero when it is within this share of its column's largest
#: value in the file (module docstring, "Negative values"); further below zero it is refused.
NEGATIVE_NOISE = 0.05


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
    """Read and parse one pgII text file (one incidence); :class:`FormatError` naming the file."""
    path = Path(path)
    data = read_file_bytes(path, MAX_BYTES, "pgII text (one incidence)")
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


def parse_pgii(text: str, path: str = "<pgII>") -> PgiiFile:  # noqa: C901
    """Parse the text of a pgII file; raise :class:`FormatError` naming the line."""
    header: dict[str, str] = {}
    sample, theta_i, phi_i, unit, wavelengths = "", None, 0.0, None, None
    rows: list[list[float]] = []
    row_lines: list[int] = []
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
                phi_i = _number(value.split()[0] if value else "", "#inphi", path, number)
                if not 0 <= phi_i <= 360:
                    raise FormatError(f"#inphi {phi_i:g} must be in [0, 360] degrees", file=path,
                                      line=number)
                phi_i %= 360.0
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
        if len(rows) >= MAX_ROWS:
            raise FormatError(f"more than {MAX_ROWS} data lines", file=path, line=number,
                              hint="a pgII file holds one incidence; split the scan")
        rows.append([theta, phi] + values)
        row_lines.append(number)
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
    # one observation direction per line: a repeat (also theta > 90 mirrored onto a direction
    # already given, or the normal at two azimuths) is named by its two lines
    seen: dict[tuple[float, float], int] = {}
    for k, (t, ph) in enumerate(zip(theta_o, phi_o, strict=True)):
        key = (round(float(t), 6), 0.0 if round(float(t), 6) == 0.0 else round(float(ph), 6) % 360.0)
        if key in seen:
            raise FormatError(f"observation direction theta {key[0]:g}, phi {key[1]:g} deg given twice "
                              f"(lines {seen[key]} and {row_lines[k]})", file=path, line=row_lines[k],
                              hint="keep one line per direction (theta > 90 is the other half of the plane)")
        seen[key] = row_lines[k]
    _check_negative(arr[:, 2:], row_lines, wavelengths, path)
    return PgiiFile(path, sample, float(theta_i), float(phi_i), unit, wavelengths, theta_o,
                    phi_o, arr[:, 2:], header)


def _check_negative(values: np.ndarray, row_lines: list[int], wavelengths: list[float] | None, path: str) -> None:
    """Refuse a value further below zero than measurement noise (module docstring, "Negative values")."""
    for k in range(values.shape[1]):
        column = values[:, k]
        if not np.any(column < 0):
            continue
        band = f"{wavelengths[k]:g} nm" if wavelengths else "Y"
        peak = float(column.max())
        if peak <= 0:
            j = int(np.argmin(column))
            raise FormatError(f"value {column[j]:g} ({band}) is negative and no value of that column is above zero",
                              file=path, line=row_lines[j],
                              hint="a column of noise around zero needs some signal to be told from an error; "
                                   "check the file's export (sign, columns)")
        j = int(np.argmin(column))
        if column[j] < -NEGATIVE_NOISE * peak:
            raise FormatError(f"value {column[j]:g} ({band}) is further below zero than measurement noise "
                              f"(at most {NEGATIVE_NOISE:g} x the column's largest value {peak:g}, i.e. "
                              f"{-NEGATIVE_NOISE * peak:.3g})", file=path, line=row_lines[j],
                              hint="check the file's export (sign, dark subtraction, columns)")


def white_reference_scale(white: PgiiFile, reflectance: float, bands: int) -> np.ndarray:
    """``(rho_w / pi) / <I_w / cos theta_w>`` per band (f_r per uA at normal incidence; see the module docstring)."""
    if white.unit != "[uA]":
        raise FormatError(f"the white reference must be raw detector current ([uA]), not {white.unit}",
                          file=white.path, hint="give the standard's raw pgII export")
    if not (0.0 < reflectance <= 1.0):
        raise FormatError(f"white reflectance {reflectance!r} must be in (0, 1]", file=white.path)
    if white.values.shape[1] != bands:
        raise FormatError(f"{white.values.shape[1]} value columns, the sample files have {bands}",
                          file=white.path, hint="measure the standard at the sample's wavelengths")
    near = white.theta_o <= 60.0
    if not np.any(near):
        raise FormatError("no reference row observed within 60 degrees of the normal", file=white.path,
                          hint="the standard must be seen near its normal")
    mean = white.values[near].mean(axis=0) / math.cos(math.radians(white.theta_i))
    if not np.all(mean > 0):
        raise FormatError("the white reference reads no signal above zero in some band", file=white.path,
                          hint="check the standard's file (shutter, detector range)")
    return reflectance / math.pi / mean


def pgii_dataset(files: Sequence[PgiiFile], *, scale: float | None = None, white: PgiiFile | None = None,
                 white_reflectance: float = 0.99):
    """One dataset from several pgII files (one incidence each).

    ``[uA]`` files need ``scale`` (``f_r`` per uA) or a ``white`` reference file (with its
    reflectance) for absolute values; without either the dataset is relative. All files must
    share the unit and the wavelengths.
    """
    from gonio.data.dataset import make_dataset, new_meta

    if not files:
        raise FormatError("no pgII files given")
    if scale is not None and white is not None:
        raise FormatError("give a scale or a white reference, not both", hint="drop one of them")
    first = files[0]
    for f in files[1:]:
        if f.unit != first.unit or f.wavelengths_nm != first.wavelengths_nm:
            raise FormatError(f"unit {f.unit} / wavelengths {f.wavelengths_nm} differ from "
                              f"{first.path}'s ({first.unit} / {first.wavelengths_nm})", file=f.path,
                              hint="one dataset needs files of the same format")
    white_scale = None
    white_meta: dict = {}       # the white reference's provenance, when one calibrates the files
    if white is not None:
        if first.unit != "[uA]":
            raise FormatError(f"a white reference calibrates raw [uA] files; these are {first.unit}",
                              file=first.path, hint="leave out the white reference")
        if white.wavelengths_nm != first.wavelengths_nm:
            raise FormatError(f"wavelengths {white.wavelengths_nm} differ from the sample's "
                              f"{first.wavelengths_nm}", file=white.path,
                              hint="measure the standard at the sample's wavelengths")
        white_scale = white_reference_scale(white, white_reflectance, first.values.shape[1])
        white_meta = {"white_reference": Path(white.path).name, "white_reflectance": white_reflectance,
                      "white_scale_fr_per_uA": white_scale.tolist()}
    relative = first.unit == "[uA]" and scale is None and white_scale is None
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
        if f.unit == "[uA]" and white_scale is not None:
            values = values * white_scale[None, :] / math.cos(math.radians(f.theta_i))
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
    negative = _negative_counts(files, parts)
    if negative:
        log.warning("negative values kept as measurement noise around zero (each within %g of its column's "
                    "largest value): %s", NEGATIVE_NOISE,
                    "; ".join(f"{b}: {v['stored']} of {v['of']}" for b, v in negative.items()))
    meta = new_meta("measured", {"name": first.sample or Path(first.path).stem},
                    {"name": "PAB pgII goniophotometer", "format": "pgii", "unit": first.unit},
                    {"source_files": [Path(f.path).name for f in files],
                     "headers": {Path(f.path).name: f.header for f in files},
                     **({"scale_fr_per_uA": scale} if scale is not None else {}),
                     **({"negative_values": negative} if negative else {}),
                     **white_meta},
                    relative=relative)
    if not first.wavelengths_nm:
        meta["colour_space"] = "linear sRGB"
    return make_dataset(pd.concat(parts, ignore_index=True), meta, source=first.path)


def _negative_counts(files: Sequence[PgiiFile], parts: list[pd.DataFrame]) -> dict:
    """``{band: {"stored", "of", "rows"}}`` of the kept negative values (as :mod:`gonio.data.formats.rgl_bsdf`)."""
    out: dict[str, dict[str, int]] = {}
    labels = [f"{w:g}" for w in files[0].wavelengths_nm] if files[0].wavelengths_nm else ["Y"]
    for k, label in enumerate(labels):
        stored = sum(int(np.count_nonzero(f.values[:, k] < 0)) for f in files)
        if stored:
            rows = sum(int(np.count_nonzero(p["beta"].to_numpy() < 0)) for p in parts[k::len(labels)])
            out[label] = {"stored": stored, "of": sum(int(f.values.shape[0]) for f in files), "rows": rows}
    return out
