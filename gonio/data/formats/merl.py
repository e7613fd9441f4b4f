"""MERL BRDF database binary files (Matusik et al. 2003): reader and writer.

Layout: three int32 ``(90, 90, 180)`` (theta_half, theta_diff, phi_diff resolutions), then
``3 x 90 x 90 x 180`` float64 values, the R block, the G block, the B block, little-endian. Table
value times the published scale factors (R 1/1500, G 1.15/1500, B 1.66/1500) is the BRDF ``f_r``
in 1/sr; negative values mark bins without data. Coordinates are Rusinkiewicz's half/difference
angles: ``theta_half`` indexed non-linearly (``i = floor(sqrt(theta_half / (pi/2)) * 90)``),
``theta_diff`` linearly over [0, pi/2), ``phi_diff`` over [0, pi) (reciprocity folds the rest).
Lookup is the reference code's nearest-lower bin (``BRDFRead.cpp``); ``beta = pi f_r``.

References
----------
W. Matusik, H. Pfister, M. Brand, L. McMillan, "A Data-Driven Reflectance Model", ACM TOG 22(3),
2003; the MERL BRDF database reference reader ``BRDFRead.cpp``. S. Rusinkiewicz, "A New Change of
Variables for Efficient BRDF Representation", EGWR 1998.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from gonio.data.formats.errors import FormatError, RegularFile

__all__ = ["MERL_SHAPE", "MERL_SCALE", "MerlBRDF", "half_diff", "read_merl", "write_merl"]

MERL_SHAPE = (90, 90, 180)
MERL_SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
_HEADER = 12
_N = MERL_SHAPE[0] * MERL_SHAPE[1] * MERL_SHAPE[2]


def half_diff(wi: np.ndarray, wo: np.ndarray):
    """Rusinkiewicz coordinates ``(theta_half, theta_diff, phi_diff)`` (radians) of unit vectors."""
    h = wi + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    theta_h = np.arccos(np.clip(h[..., 2], -1.0, 1.0))
    phi_h = np.arctan2(h[..., 1], h[..., 0])
    # rotate wi by -phi_h about z, then by -theta_h about y
    c, s = np.cos(-phi_h), np.sin(-phi_h)
    x = c * wi[..., 0] - s * wi[..., 1]
    y = s * wi[..., 0] + c * wi[..., 1]
    z = wi[..., 2]
    c2, s2 = np.cos(-theta_h), np.sin(-theta_h)
    dx = c2 * x + s2 * z
    dz = -s2 * x + c2 * z
    theta_d = np.arccos(np.clip(dz, -1.0, 1.0))
    phi_d = np.arctan2(y, dx)
    return theta_h, theta_d, phi_d


def _indices(theta_h, theta_d, phi_d):
    th = np.where(theta_h <= 0, 0.0, np.sqrt(np.clip(theta_h, 0, None) / (np.pi / 2) * 90 * 90))
    i_h = np.clip(th.astype(np.intp), 0, MERL_SHAPE[0] - 1)
    i_d = np.clip((theta_d / (np.pi / 2) * 90).astype(np.intp), 0, MERL_SHAPE[1] - 1)
    phi = np.where(phi_d < 0, phi_d + np.pi, phi_d)
    i_p = np.clip((phi / np.pi * 180).astype(np.intp), 0, MERL_SHAPE[2] - 1)
    return i_h, i_d, i_p


class MerlBRDF:
    """An isotropic RGB BRDF table; ``table[c, i_h, i_d, i_p]`` is ``f_r`` (scales applied)."""

    def __init__(self, table: np.ndarray, path: str | os.PathLike = "<merl>"):
        self.table = np.asarray(table, dtype=float)
        self.path = str(path)

    def f_r(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """``f_r`` (1/sr) per channel ``(..., 3)``; NaN in bins without data."""
        i_h, i_d, i_p = _indices(*half_diff(np.asarray(wi, float), np.asarray(wo, float)))
        values = np.moveaxis(self.table[:, i_h, i_d, i_p], 0, -1)
        return np.where(values < 0, np.nan, values)

    def to_dataset(self, geometries: pd.DataFrame | None = None):
        """Dataset (RGB, linear sRGB as the database's) at ``geometries``; bins without data left out.

        The default geometries are in-plane curves at theta_i = 0, 15, ..., 75 deg, s = -80..80
        deg every 2 deg.
        """
        from gonio.data.dataset import make_dataset, new_meta
        from gonio.data.geometry import direction, in_plane_geometry

        if geometries is None:
            s = np.arange(-80.0, 80.0 + 1e-9, 2.0)
            theta = np.arange(0.0, 76.0, 15.0)
            ti, ss = np.repeat(theta, s.size), np.tile(s, theta.size)
            to, po = in_plane_geometry(ti, ss, 0.0)
            geometries = pd.DataFrame({"theta_i": ti, "phi_i": 0.0, "theta_o": to, "phi_o": po})
        geo = geometries[["theta_i", "phi_i", "theta_o", "phi_o"]].drop_duplicates()
        wi = direction(geo["theta_i"].to_numpy(float), geo["phi_i"].to_numpy(float))
        wo = direction(geo["theta_o"].to_numpy(float), geo["phi_o"].to_numpy(float))
        beta = np.pi * self.f_r(wi, wo)
        keep = np.all(np.isfinite(beta), axis=1)
        if not keep.any():
            raise FormatError("no requested geometry falls in a bin with data", file=self.path)
        parts = []
        for k, ch in enumerate("RGB"):
            part = geo[keep].copy()
            part["channel"] = ch
            part["beta"] = beta[keep, k]
            part["u_beta"] = 0.0
            part["n"] = 1
            parts.append(part)
        meta = new_meta("measured", {"name": Path(self.path).stem},
                        {"name": "MERL BRDF database", "format": "merl"},
                        {"source_file": Path(self.path).name,
                         "lookup": "nearest-lower bin (BRDFRead.cpp)"},
                        colour_space="linear sRGB")
        return make_dataset(pd.concat(parts, ignore_index=True), meta, source=self.path)


def read_merl(path: str | os.PathLike) -> MerlBRDF:
    """Read a MERL ``.binary`` file; raise :class:`FormatError` naming the byte offset."""
    path = Path(path)
    expected = _HEADER + 3 * _N * 8
    # the size is fixed: checked (from the header and the file's size) before the body is read
    with RegularFile(path, expected + 4096, "MERL .binary") as fh:
        head = fh.read(0, _HEADER)
        if len(head) < _HEADER:
            raise FormatError(f"file is {len(head)} bytes, shorter than the 12-byte header",
                              file=path, offset=0, hint="expected a MERL .binary BRDF file")
        dims = struct.unpack("<3i", head)
        if dims != MERL_SHAPE:
            raise FormatError(f"header gives resolutions {dims}, expected {MERL_SHAPE}",
                              file=path, offset=0,
                              hint="only the isotropic 90 x 90 x 180 MERL layout is read")
        if fh.size != expected:
            raise FormatError(f"file is {fh.size} bytes, expected {expected} "
                              f"({'truncated' if fh.size < expected else 'trailing data'})",
                              file=path, offset=min(fh.size, expected))
        data = fh.read_all()
    raw = np.frombuffer(data, dtype="<f8", count=3 * _N, offset=_HEADER)
    bad = ~np.isfinite(raw)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise FormatError("value is NaN or infinite", file=path, offset=_HEADER + 8 * k)
    table = raw.reshape((3,) + MERL_SHAPE) * MERL_SCALE[:, None, None, None]
    table = np.where(raw.reshape((3,) + MERL_SHAPE) < 0, -1.0, table)
    return MerlBRDF(table, path)


def write_merl(path: str | os.PathLike, f_r: np.ndarray | Callable) -> Path:
    """Write a MERL file from a table ``(3, 90, 90, 180)`` of ``f_r`` or a function.

    A function ``f_r(theta_half, theta_diff, phi_diff) -> (..., 3)`` (radians) is sampled at the
    lower corner of each bin, where the reader's lookup lands exactly. Values are divided by the
    published scale factors; negative entries stay negative (no data).
    """
    if callable(f_r):
        i_h, i_d, i_p = np.meshgrid(*(np.arange(n) for n in MERL_SHAPE), indexing="ij")
        theta_h = (i_h / 90.0) ** 2 * (np.pi / 2)
        theta_d = i_d / 90.0 * (np.pi / 2)
        phi_d = i_p / 180.0 * np.pi
        table = np.moveaxis(np.asarray(f_r(theta_h, theta_d, phi_d), dtype=float), -1, 0)
    else:
        table = np.asarray(f_r, dtype=float)
    if table.shape != (3,) + MERL_SHAPE:
        raise ValueError(f"table shape {table.shape}, expected {(3,) + MERL_SHAPE}")
    raw = np.where(table < 0, table, table / MERL_SCALE[:, None, None, None])
    path = Path(path)
    path.write_bytes(struct.pack("<3i", *MERL_SHAPE) + raw.astype("<f8").tobytes())
    return path
