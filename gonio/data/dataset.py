"""Radiance-coefficient datasets: the format, its validation and its (atomic) I/O.

The format's constants and `DatasetError` are the leaf `gonio.data.schema`, the checks of the two
files `gonio.data.validation`, the atomic writers `gonio.data.atomic`; ``simulate`` and ``compare``
import the readers and writers from here (this module also offers `atomic_write`,
`write_files_together` and `remove_stale_temp_files` under their long-standing names).

A dataset is a directory with two files (docs/dataset.md):

``radiance.csv``
    one row per (geometry, wavelength), columns in this order::

        theta_i,phi_i,theta_o,phi_o,wavelength_nm,beta,u_beta,n

    angles in degrees in the fabric frame (z = fabric normal, x = warp), ``theta`` in [0, 90],
    ``phi`` in [0, 360); directions point away from the sample. ``beta`` is the radiance
    coefficient (radiance factor, ``beta = pi f_r``), ``u_beta`` its standard uncertainty, ``n`` the
    number of readings (or photons / rays) behind it.
``meta.json``
    ``{"schema": "radiance-dataset/1", "kind": "measured"|"simulated", "sample": {...},
    "instrument"|"model": {...}, "wavelengths_nm": [...], "created": ISO-8601, "software": {...},
    "provenance": {...}}``; free-form beyond these keys.

Reading validates everything and raises `DatasetError`, whose message names the file, the
row (the line number in the file, the header being line 1), the column and the problem. Writing is
atomic per file (temporary file, fsync, rename) and ``meta.json`` is written last and carries the
SHA-256 of ``radiance.csv``, so a crash between the two renames is detected on reading instead of
silently pairing new values with old metadata.

Conventions decided here (the design is silent on them):

- A geometry with ``theta_o = 0`` has no meaningful ``phi_o``; it is stored with
  ``phi_o = phi_i + 180`` (the in-plane convention's ``s = 0``), so two writers cannot create two
  rows for the same direction. The same holds for ``theta_i = 0`` only in the sense that ``phi_i``
  is kept as given: at normal incidence ``phi_i`` names the plane in which the in-plane signed angle
  is measured (the instrument's detector plane / sample rotation).
- ``beta`` may be slightly negative in measured data (dark-subtracted noise); it must be finite.
- Interpolation (`Dataset.interpolate`) lives in `gonio.data.interpolate`.

RGB datasets (docs/dataset.md): a ``channel`` column (``R``, ``G``, ``B``, or ``Y`` for a
photometric measurement) stands in place of ``wavelength_nm``::

    theta_i,phi_i,theta_o,phi_o,channel,beta,u_beta,n

and ``meta.json`` names the colour space (``"colour_space": "linear sRGB"`` by default; only linear
spaces, ``"linear NAME"`` with NAME a colour-science RGB colour space) and lists the
``"channels"``. The spectral format and its bytes are unchanged. A measurement in raw detector
units carries ``"relative": true``: its shapes are meaningful, its absolute level is not.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import io
import json
import os
import platform
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from gonio.data.atomic import (  # noqa: F401  (also offered here: their long-standing home)
    atomic_write,
    fsync_dir,
    remove_stale_temp_files,
    write_files_together,
)
from gonio.data.geometry import signed_angle

__all__ = [
    "CHANNELS",
    "COLUMNS",
    "DEFAULT_COLOUR_SPACE",
    "RGB_COLUMNS",
    "GEOMETRY",
    "SCHEMA",
    "Dataset",
    "DatasetError",
    "atomic_write",
    "make_dataset",
    "new_meta",
    "read_dataset",
    "remove_stale_temp_files",
    "write_dataset",
    "write_files_together",
]

from gonio.data.schema import (  # noqa: F401
    ANGLE_TOL_DEG,
    BETA_MAX,
    CHANNELS,
    COLUMNS,
    CSV_NAME,
    DEFAULT_COLOUR_SPACE,
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
from gonio.data.validation import canonical_phi, file_kind, require_regular_file, validate_meta, validate_table

_FLOAT_FORMAT = "%.10g"

# --------------------------------------------------------------------------------------------
# the dataset


class Dataset:
    """A validated radiance-coefficient dataset held in memory.

    Create with `make_dataset` or `read_dataset`; the table is sorted by geometry and
    wavelength and must not be modified in place (derive new datasets with `with_values`).
    """

    def __init__(self, table: pd.DataFrame, meta: dict, path: Path | None = None):
        self.table = table
        self.meta = meta
        self.path = path
        self._derived: dict = {}

    def derived(self, key: Any, build: Callable[[], Any]) -> Any:
        """A value computed from this dataset's table once and kept with it.

        ``build()`` runs the first time ``key`` is asked for: :mod:`gonio.data.interpolate` keeps
        its triangulations here. Valid because a dataset's table is never modified in place.
        """
        if key not in self._derived:
            self._derived[key] = build()
        return self._derived[key]

    # --- descriptive properties -------------------------------------------------------------
    @property
    def kind(self) -> str:
        """What the dataset holds: ``measured``, ``simulated``, ... (meta ``kind``)."""
        return self.meta["kind"]

    @property
    def name(self) -> str:
        """The sample's name (meta ``sample.name``), else the folder's name."""
        sample = self.meta.get("sample") or {}
        name = sample.get("name") if isinstance(sample, dict) else None
        if name:
            return str(name)
        return self.path.name if self.path is not None else "dataset"

    @property
    def is_rgb(self) -> bool:
        """True for a dataset of colour channels (a ``channel`` column), False for spectra."""
        return "channel" in self.table.columns

    @property
    def band_column(self) -> str:
        """``"channel"`` for an RGB dataset, ``"wavelength_nm"`` for a spectral one."""
        return "channel" if self.is_rgb else "wavelength_nm"

    @property
    def channels(self) -> tuple[str, ...]:
        """The channels of an RGB dataset in canonical order (R, G, B, Y); () for spectra."""
        if not self.is_rgb:
            return ()
        present = set(self.table["channel"])
        return tuple(c for c in CHANNELS if c in present)

    @property
    def bands(self):
        """The wavelengths (spectral, a float array) or the channels (RGB, a tuple)."""
        return self.channels if self.is_rgb else self.wavelengths_nm

    @property
    def colour_space(self) -> str | None:
        """Colour space of an RGB dataset (``"linear sRGB"`` unless meta.json names another)."""
        if not self.is_rgb:
            return None
        return str(self.meta.get("colour_space", DEFAULT_COLOUR_SPACE))

    @property
    def relative(self) -> bool:
        """True when the values are in raw (relative) units (``"relative": true`` in meta.json)."""
        return self.meta.get("relative") is True

    @property
    def wavelengths_nm(self) -> np.ndarray:
        """The dataset's wavelengths, ascending (empty for an RGB dataset)."""
        if self.is_rgb:
            return np.array([], dtype=float)
        return np.unique(self.table["wavelength_nm"].to_numpy())

    @property
    def source(self) -> str:
        """Where the data came from (path or name), for messages."""
        return str(self.path) if self.path is not None else self.name

    @property
    def complete(self) -> bool:
        """False when the meta says the run is incomplete, True otherwise.

        Incomplete is ``"complete": false`` at the top level or in ``provenance``, as ``gonio
        acquire`` writes it for a stopped run.
        """
        provenance = self.meta.get("provenance") or {}
        flag = self.meta.get("complete", provenance.get("complete"))
        return flag is not False

    def completeness(self) -> str:
        """How complete the data are, for people: ``"17 of 53 planned points (68% missing)"``."""
        provenance = self.meta.get("provenance") or {}
        measured, planned = provenance.get("points_measured"), provenance.get("points_planned")
        if isinstance(measured, int) and isinstance(planned, int) and planned > 0:
            missing = max(planned - measured, 0)
            if missing == 0:
                return f"all {planned} planned points measured"
            return (f"{measured} of {planned} planned points measured "
                    f"({missing} = {100.0 * missing / planned:.0f}% missing)")
        return "complete" if self.complete else "marked incomplete (fraction not recorded)"

    def content_sha256(self) -> str:
        """SHA-256 of the canonical ``radiance.csv`` bytes (equal data give equal hashes)."""
        cached = getattr(self, "_content_sha256", None)
        if cached is None:
            cached = hashlib.sha256(_csv_bytes(self.table)).hexdigest()
            self._content_sha256 = cached
        return cached

    def __repr__(self) -> str:
        return (f"Dataset(name={self.name!r}, kind={self.kind!r}, rows={len(self.table)}, "
                f"geometries={len(self.geometries())}, "
                + (f"channels={''.join(self.channels)})" if self.is_rgb
                   else f"wavelengths={len(self.wavelengths_nm)})"))

    def __len__(self) -> int:
        return len(self.table)

    # --- views -----------------------------------------------------------------------------
    def geometries(self) -> pd.DataFrame:
        """Unique geometries ``(theta_i, phi_i, theta_o, phi_o)``, sorted."""
        return self.table[list(GEOMETRY)].drop_duplicates().reset_index(drop=True)

    def to_frame(self) -> pd.DataFrame:
        """A pandas copy of the rows with the signed in-plane angle ``s`` (NaN out of plane)."""
        frame = self.table.copy()
        frame["s"] = signed_angle(frame["theta_i"], frame["phi_i"], frame["theta_o"],
                                  frame["phi_o"])
        return frame

    def spectrum(self, theta_i: float, phi_i: float, theta_o: float, phi_o: float) -> pd.DataFrame:
        """Rows at one geometry (angles within 1e-6 degrees), sorted by wavelength."""
        t = self.table
        probe = canonical_phi(pd.DataFrame({"theta_i": [theta_i], "phi_i": [phi_i],
                                             "theta_o": [theta_o], "phi_o": [phi_o]}))
        mask = np.ones(len(t), dtype=bool)
        for col in GEOMETRY:
            value = float(probe[col].iloc[0])
            diff = np.abs(t[col].to_numpy() - value)
            if col.startswith("phi"):
                diff = np.minimum(diff, 360.0 - diff)
            mask &= diff < ANGLE_TOL_DEG
        rows = t[mask]
        if rows.empty:
            raise DatasetError(
                f"no data at theta_i={theta_i:g}, phi_i={phi_i:g}, theta_o={theta_o:g}, "
                f"phi_o={phi_o:g}", file=self.source,
                hint="use Dataset.geometries() to list what was measured, or interpolate()")
        return rows.reset_index(drop=True)

    def in_plane(self, theta_i: float | None = None, phi_i: float | None = None,
                 wavelength_nm: float | None = None) -> pd.DataFrame:
        """In-plane rows with the signed observation angle ``s``, sorted by theta_i, wavelength, s."""
        frame = self.to_frame()
        frame = frame[np.isfinite(frame["s"].to_numpy())]
        for col, value in (("theta_i", theta_i), ("phi_i", phi_i),
                           ("wavelength_nm", wavelength_nm)):
            if value is not None and col == "wavelength_nm" and self.is_rgb:
                frame = frame[frame["channel"] == str(value)]
            elif value is not None:
                frame = frame[np.abs(frame[col].to_numpy() - float(value)) < ANGLE_TOL_DEG]
        band = self.band_column
        if self.is_rgb:
            frame["_order"] = [CHANNELS.index(c) for c in frame["channel"]]
            frame = frame.sort_values(["theta_i", "phi_i", "_order", "s"], kind="mergesort")
            return frame.drop(columns="_order").reset_index(drop=True)
        frame = frame.sort_values(["theta_i", "phi_i", band, "s"], kind="mergesort")
        return frame.reset_index(drop=True)

    def colour_at(self, theta_i: float, phi_i: float, theta_o: float, phi_o: float,
                  illuminant: str = "D65"):
        """HSV / linear-sRGB summary of the spectrum at one geometry (see `gonio.data.colour`)."""
        from gonio.data.colour import rgb_colour, spectrum_colour

        rows = self.spectrum(theta_i, phi_i, theta_o, phi_o)
        if self.is_rgb:
            values = dict(zip(rows["channel"], rows["beta"], strict=True))
            return rgb_colour(values, colour_space=self.colour_space or DEFAULT_COLOUR_SPACE)
        return spectrum_colour(rows["wavelength_nm"].to_numpy(), rows["beta"].to_numpy(),
                               illuminant=illuminant)

    def with_values(self, beta, u_beta=None, meta_update: Mapping | None = None) -> Dataset:
        """A new dataset with the same rows and new ``beta`` (and ``u_beta``) values."""
        table = self.table.copy()
        table["beta"] = np.asarray(beta, dtype=float) * np.ones(len(table))
        if u_beta is not None:
            table["u_beta"] = np.asarray(u_beta, dtype=float) * np.ones(len(table))
        meta = json.loads(json.dumps(self.meta))
        if meta_update:
            meta.update(meta_update)
        return make_dataset(table, meta, source=self.source)

    # --- interpolation ---------------------------------------------------------------------
    def interpolate(self, theta_i, phi_i, theta_o, phi_o, band):
        """``(beta, u_beta)`` at arbitrary geometries and wavelengths (or channels) inside the data.

        See `gonio.data.interpolate.interpolate`.
        """
        from gonio.data.interpolate import interpolate

        return interpolate(self, theta_i, phi_i, theta_o, phi_o, band)


# --------------------------------------------------------------------------------------------
# construction, reading and writing


def _software() -> dict:
    from gonio.version import software

    return {**software(), "python": platform.python_version(), "numpy": np.__version__,
            "pandas": pd.__version__}


def new_meta(kind: str, sample: Mapping, source: Mapping | None = None,
             provenance: Mapping | None = None, *, created: str | None = None,
             **extra: Any) -> dict:
    """Metadata for a new dataset.

    ``source`` is stored under ``"instrument"`` for measured data and ``"model"`` for simulated
    data. ``created`` defaults to now (UTC, ISO-8601); pass a fixed value for reproducible files.
    """
    if kind not in KINDS:
        raise DatasetError(f"kind {kind!r} is not one of {KINDS}")
    meta = {
        "schema": SCHEMA,
        "kind": kind,
        "sample": dict(sample),
        ("instrument" if kind == "measured" else "model"): dict(source or {}),
        "wavelengths_nm": [],
        "created": created or _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "software": _software(),
        "provenance": dict(provenance or {}),
    }
    meta.update(extra)
    return meta


def make_dataset(table: pd.DataFrame | Mapping[str, Iterable], meta: Mapping,
                 *, source: str | None = None) -> Dataset:
    """Validate ``table`` (columns `COLUMNS`) and ``meta``; return a `Dataset`.

    ``phi`` values are wrapped to [0, 360) and the normal direction's ``phi_o`` is canonicalised
    before validation; ``meta["wavelengths_nm"]`` is filled from the table.
    """
    frame = pd.DataFrame(table).copy()
    for col in ("phi_i", "phi_o"):
        if col in frame.columns:
            values = pd.to_numeric(frame[col], errors="coerce")
            frame[col] = np.mod(values, 360.0)
    if "n" in frame.columns:
        frame["n"] = pd.to_numeric(frame["n"], errors="coerce")
    for columns in (COLUMNS, RGB_COLUMNS):
        if all(c in frame.columns for c in columns):
            frame = frame[list(columns)]
    meta = validate_meta(json.loads(json.dumps(dict(meta), default=_json_default)), source)
    frame = validate_table(frame, source, line_offset=0)
    dataset = Dataset(frame, meta)
    _fill_band_meta(dataset)
    return dataset


def _fill_band_meta(dataset: Dataset) -> None:
    """``wavelengths_nm`` (spectral) or ``channels`` and ``colour_space`` (RGB) from the table."""
    meta = dataset.meta
    if dataset.is_rgb:
        meta["wavelengths_nm"] = []
        meta["channels"] = list(dataset.channels)
        meta.setdefault("colour_space", DEFAULT_COLOUR_SPACE)
    else:
        meta["wavelengths_nm"] = [float(w) for w in dataset.wavelengths_nm]


def _json_default(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _csv_bytes(table: pd.DataFrame) -> bytes:
    buffer = io.StringIO()
    table.to_csv(buffer, index=False, float_format=_FLOAT_FORMAT, lineterminator="\n")
    return buffer.getvalue().encode("utf-8")


def write_dataset(dataset: Dataset, out_dir: str | os.PathLike) -> Path:
    """Write ``dataset`` to ``out_dir`` (created if needed) atomically; return the directory.

    ``radiance.csv`` first, then ``meta.json`` carrying its SHA-256: each file is replaced
    atomically, and a reader detects a crash between the two. Other files in ``out_dir`` (a run's
    journal, for example) are left alone. A table that :func:`read_dataset` would refuse (a NaN, a
    negative ``beta``, ...) is refused first with its :class:`DatasetError`; nothing is written.
    The CSV is formatted deterministically (``%.10g``), so equal datasets give byte-identical files.
    """
    out = Path(out_dir)
    validate_table(dataset.table, str(out / CSV_NAME), line_offset=0)   # what the reader would refuse
    out.mkdir(parents=True, exist_ok=True)
    data = _csv_bytes(dataset.table)
    meta = json.loads(json.dumps(dataset.meta, default=_json_default))
    meta["wavelengths_nm"] = [float(w) for w in dataset.wavelengths_nm]
    if dataset.is_rgb:
        meta["channels"] = list(dataset.channels)
        meta.setdefault("colour_space", DEFAULT_COLOUR_SPACE)
    meta["files"] = {CSV_NAME: {"sha256": hashlib.sha256(data).hexdigest(),
                                "rows": int(len(dataset.table))}}
    atomic_write(out / CSV_NAME, data)
    atomic_write(out / META_NAME,
                  (json.dumps(meta, indent=2, sort_keys=False, allow_nan=False) + "\n").encode())
    fsync_dir(out)
    dataset.path = out
    dataset.meta = meta
    return out


def read_dataset(path: str | os.PathLike) -> Dataset:  # noqa: C901
    """Read and validate the dataset in directory ``path``; raise :class:`DatasetError`."""
    root = Path(path)
    hint = f"a dataset is a directory holding {CSV_NAME} and {META_NAME}"
    if not root.exists():
        if os.path.islink(root):
            require_regular_file(root)    # names the looping or dangling link
        raise DatasetError("no such dataset directory", file=root, hint=hint)
    if root.is_file():
        if root.name in (CSV_NAME, META_NAME):
            root = root.parent
        else:
            raise DatasetError("is a file, not a dataset directory", file=root,
                               hint=f"pass the directory holding {CSV_NAME} and {META_NAME}")
    elif not root.is_dir():
        kind = file_kind(os.stat(root).st_mode)
        raise DatasetError(f"is {kind}, not a dataset directory", file=root, hint=hint)
    csv_path, meta_path = root / CSV_NAME, root / META_NAME
    for p in (csv_path, meta_path):
        require_regular_file(p)
    raw_meta = meta_path.read_bytes()
    if not raw_meta.strip():
        raise DatasetError("file is empty", file=meta_path)
    try:
        meta = json.loads(raw_meta.decode("utf-8"))
    except RecursionError:
        raise DatasetError("nested too deeply to be read (JSON nesting exhausts the stack)",
                           file=meta_path,
                           hint="meta.json holds a few levels of keys; regenerate it") from None
    except UnicodeDecodeError as exc:
        raise DatasetError(f"not UTF-8 text ({exc.reason})", file=meta_path) from None
    except json.JSONDecodeError as exc:
        raise DatasetError(f"invalid JSON: {exc.msg}", file=meta_path, row=exc.lineno) from None
    meta = validate_meta(meta, str(meta_path))
    data = csv_path.read_bytes()
    if not data.strip():
        raise DatasetError("file is empty", file=csv_path,
                           hint=f"expected the header {','.join(COLUMNS)} and data rows")
    expected = meta.get("files", {}).get(CSV_NAME, {}).get("sha256")
    if expected and hashlib.sha256(data).hexdigest() != expected:
        raise DatasetError(f"does not match the checksum recorded in {META_NAME}", file=csv_path,
                           hint="the dataset was changed after writing or a write was interrupted; "
                                "rewrite it with gonio.data.write_dataset (a run can be "
                                "rebuilt from its journal)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DatasetError(f"not UTF-8 text ({exc.reason})", file=csv_path) from None
    try:
        table = pd.read_csv(io.StringIO(text), dtype=str, keep_default_na=False,
                            skipinitialspace=True)
    except pd.errors.ParserError as exc:
        raise DatasetError(f"not a valid CSV table ({str(exc).strip()})", file=csv_path) from None
    except pd.errors.EmptyDataError:
        raise DatasetError("file is empty", file=csv_path) from None
    # pandas pads short rows with NaN/"" and rejects long ones above; name the short row precisely
    table = validate_table(table, str(csv_path))
    if "channel" in table.columns:
        dataset = Dataset(table, meta, path=root)
        listed_channels = meta.get("channels")
        if listed_channels is not None and tuple(listed_channels) != dataset.channels:
            raise DatasetError(f"key 'channels' lists {listed_channels} but {CSV_NAME} holds "
                               f"{list(dataset.channels)}", file=meta_path,
                               hint="the two files do not belong together")
        if meta.get("wavelengths_nm"):
            raise DatasetError("key 'wavelengths_nm' lists wavelengths but the data are RGB "
                               "channels", file=meta_path, hint="the two files do not belong together")
        _fill_band_meta(dataset)
        return dataset
    listed = meta.get("wavelengths_nm")
    if listed is not None:
        try:
            listed_arr = np.sort(np.asarray(listed, dtype=float).ravel())
        except (TypeError, ValueError):
            raise DatasetError("key 'wavelengths_nm' must be a list of numbers",
                               file=meta_path) from None
        actual = np.unique(table["wavelength_nm"].to_numpy())
        if listed_arr.shape != actual.shape or not np.allclose(listed_arr, actual, atol=1e-6):
            raise DatasetError(
                f"key 'wavelengths_nm' lists {listed_arr.size} wavelengths that do not match the "
                f"{actual.size} in {CSV_NAME}", file=meta_path,
                hint="the two files do not belong together")
    else:
        meta["wavelengths_nm"] = [float(w) for w in np.unique(table["wavelength_nm"])]
    return Dataset(table, meta, path=root)
