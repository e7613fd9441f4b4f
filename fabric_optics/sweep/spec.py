"""What a sweep is: its parameters, points, tasks and seeds (``simulate sweep``; decisions: :mod:`fabric_optics.sweep.runner`).

:func:`parse_params` reads ``--param NAME=v1,v2,...`` into :class:`SweepParameter` (names as
``simulate fit --free`` names them: :mod:`fabric_optics.paths`); :class:`SweepSpec` holds the config,
plan, parameters, method, seed and accuracy, builds every point's config before any work and
lists the (point, wavelength) tasks with their seeds (:func:`task_seed`).

Parameters and points
---------------------
A swept parameter is a numeric config field named as ``simulate fit`` names its free
parameters (the same machinery, :mod:`fabric_optics.paths`): a dotted TOML path with list indices
(``particles.volume_fraction``, ``fiber.dye.bands[0].peak_per_um``, ``weave.spacing_um``) or
one of the single-field aliases ``volume_fraction``, ``radius``, ``rms_slope``. The multi-field
aliases ``dye``/``dye-peaks`` and the run settings (``seed``, ``method.*``, ``wavelengths.*``)
are refused: a sweep sets one field to one value, and the run settings have their own flags.
Several ``--param`` give the Cartesian product (the first parameter varies slowest); every
point's config is built and validated by :func:`simulate.config.parse_config` before any work,
so a value out of a field's range is one line naming the point and the field (exit 2). Before
that, the grid is counted: at most :data:`~fabric_optics.sweep.spec.MAX_POINTS` (10 000) points and
:data:`~fabric_optics.sweep.spec.MAX_TASKS` (100 000) tasks, and ``simulate sweep`` estimates the cost
of the costliest of up to 9 evenly spaced points times the points per worker
(:mod:`simulate.budget`; refused beyond a day). A point's directory is always
``points/<label>`` inside the sweep (:func:`~fabric_optics.sweep.spec.point_dir`; ``compare`` refuses a
``sweep.json`` whose point ``dir`` leads elsewhere). Point datasets are written as whole folders
(:mod:`simulate.outdir`); a full disk is one line naming the file, the finished tasks kept.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fabric_optics import paths as config_paths
from fabric_optics.paths import toml_dumps
from gonio.acquisition.plan import Plan
from simulate.config import ConfigError, SimulationConfig, parse_config
from simulate.virtual import FABRIC_METHODS

__all__ = ["GENERATOR", "SCHEMA", "SWEEP_NAME", "SUMMARY_NAME", "TASKS_DIR", "POINTS_DIR", "LOCK_NAME",
           "SweepError", "SweepParameter", "parse_params", "SweepPoint", "SweepTask", "task_seed", "SweepSpec",
           "point_dir", "MAX_POINTS", "MAX_TASKS"]

GENERATOR = "simulate sweep"
SCHEMA = "simulate-sweep/1"
SWEEP_NAME = "sweep.json"
SUMMARY_NAME = "summary.csv"
TASKS_DIR = "tasks"
POINTS_DIR = "points"
LOCK_NAME = ".sweep.lock"
_ALIASES = ("volume_fraction", "radius", "rms_slope")
#: Bounds of a sweep, checked from the number of values before any point's config is built: 10 000
#: points (each a validated config in memory and a dataset on disk) and 100 000 tasks (one file
#: each in ``tasks/``; 3 000 points of the 33-wavelength red-cotton plan).
MAX_POINTS = 10_000
MAX_TASKS = 100_000


class SweepError(ValueError):
    """A sweep that cannot start (bad ``--param``, bad ``--out``, another spec): one line, exit 2."""


# ------------------------------------------------------------------------------------------
# parameters and points


@dataclass(frozen=True)
class SweepParameter:
    """One swept config field: the name as given, its dotted config path and its values."""

    name: str
    path: str
    values: tuple[float | int, ...]


def _value_text(v: float | int) -> str:
    """Shortest text that reads back as the value (``0.05``, ``1e-05``, ``8``): directory names."""
    return str(v) if isinstance(v, int) else repr(float(v))


def _run_setting(path: str) -> bool:
    return path == "seed" or path.startswith(("method.", "wavelengths."))


def parse_params(specs: list[str], config: SimulationConfig) -> list[SweepParameter]:
    """Swept parameters from ``NAME=v1,v2,...`` strings (one per ``--param``).

    Raises
    ------
    SweepError
        Malformed text, a value that is not a finite number, a value given twice, an unknown or non-numeric field, a multi-field alias, a run
        setting, or one field named twice. Nothing is computed before these checks.
    """
    data = tomllib.loads(config.text)
    out: list[SweepParameter] = []
    for spec in specs:
        name, sep, values_text = spec.partition("=")
        name = name.strip()
        if not sep or not name or not values_text.strip():
            raise SweepError(f"--param {spec!r}: expected NAME=v1,v2,... (a config field and its values)")
        if name in ("dye", "dye-peaks"):
            raise SweepError(f"--param {name}: names several dye coefficients; a sweep sets one field, e.g. "
                             "fiber.dye.bands[0].peak_per_um")
        if _run_setting(name):       # refused whether or not the config writes it (defaults are not written)
            raise SweepError(f"--param {name}: {name} is a run setting, not a model parameter "
                             "(use --seed, --method, --target-rel-err; the plan gives the wavelengths)")
        try:
            paths = config_paths.expand(name, data) if name in _ALIASES else [name]
            config_paths.split(paths[0])
            current = config_paths.get(data, paths[0])
        except (config_paths.PathError, KeyError):
            fields = ", ".join(sorted(f for f in set(config_paths.numeric_leaves(data, "")) if not _run_setting(f)))
            raise SweepError(f"--param {name}: unknown parameter: the config {config.name} has no such numeric "
                             f"field (its fields: {fields}; aliases: {', '.join(_ALIASES)})") from None
        path = paths[0]
        if isinstance(current, bool) or not isinstance(current, (int, float)):
            raise SweepError(f"--param {name}: {path} is not a number in the config (a table or text)")
        if _run_setting(path):
            raise SweepError(f"--param {name}: {path} is a run setting, not a model parameter "
                             "(use --seed, --method, --target-rel-err; the plan gives the wavelengths)")
        if any(p.path == path for p in out):
            raise SweepError(f"--param {name}: {path} is swept twice")
        values: list[float | int] = []
        for text in values_text.split(","):
            text = text.strip()
            try:
                value = float(text)
            except ValueError:
                raise SweepError(f"--param {name}: {text!r} is not a number "
                                 f"(expected {name}=v1,v2,...)") from None
            if not math.isfinite(value):
                raise SweepError(f"--param {name}: {text!r} is not a finite number")
            if isinstance(current, int) and value.is_integer():
                # an integer in the config stays one (points_per_span, sides); a float where the
                # schema wants an integer is refused by the config parser, naming the field
                value = int(value)
            if value in values:
                raise SweepError(f"--param {name}: the value {text} is given twice")
            values.append(value)
        out.append(SweepParameter(name, path, tuple(values)))
    if not out:
        raise SweepError("--param: no parameter to sweep")
    return out


@dataclass(frozen=True)
class SweepPoint:
    """One parameter point: its index in the product, its values and its validated config."""

    index: int
    values: tuple[float | int, ...]
    label: str
    config: SimulationConfig = field(repr=False)

    @property
    def dir(self) -> str:
        """The point's dataset directory, relative to the sweep directory."""
        return f"{POINTS_DIR}/{self.label}"


def point_dir(sweep_dir: str | Path, rel: object) -> Path:
    """``sweep_dir / rel`` for a point's ``dir`` (``points/<label>``), refused unless it stays inside.

    A point's directory is always ``points/`` followed by one name (no ``/``, not ``.`` or
    ``..``), and must resolve (symbolic links followed) inside ``sweep_dir/points``: a crafted
    ``sweep.json`` naming ``../..`` is a :class:`SweepError`, never followed.

    Examples
    --------
    >>> point_dir("/s", "points/radius=0.25").as_posix()
    '/s/points/radius=0.25'
    """
    base = Path(sweep_dir)
    parts = rel.split("/") if isinstance(rel, str) else []
    if len(parts) != 2 or parts[0] != POINTS_DIR or parts[1] in ("", ".", "..") or "\\" in parts[1] \
            or "\0" in parts[1]:
        raise SweepError(f"{base / SWEEP_NAME}: point dir {rel!r} is not {POINTS_DIR}/<name> inside the sweep directory")
    path = base / POINTS_DIR / parts[1]
    if not path.resolve().is_relative_to((base / POINTS_DIR).resolve()):
        raise SweepError(f"{base / SWEEP_NAME}: point dir {rel!r} leads outside the sweep directory "
                         "(a symbolic link); refusing to follow it")
    return path


@dataclass(frozen=True)
class SweepTask:
    """One task of a sweep: a point at one wavelength, or a point at all the plan's wavelengths.

    ``id`` names its file: ``p003_w0550``, or ``p003`` with ``wavelength_nm`` None (the Monte Carlo's
    tasks, :meth:`SweepSpec.tasks`).
    """

    point: SweepPoint
    wavelength_nm: float | None
    seed: int

    @property
    def id(self) -> str:
        """The task's name, its file's stem: ``p003_w0550`` (a point at a wavelength) or ``p003``."""
        wl = self.wavelength_nm
        if wl is None:
            return f"p{self.point.index:03d}"
        text = f"{int(wl):04d}" if wl == int(wl) else f"{wl:09.4f}".rstrip("0").replace(".", "p")
        return f"p{self.point.index:03d}_w{text}"

    @property
    def what(self) -> str:
        """The task's wavelengths in words (failure lines)."""
        return "all wavelengths" if self.wavelength_nm is None else f"{self.wavelength_nm:g} nm"


def task_seed(seed: int, point_index: int, wavelength_nm: float) -> int:
    """The seed of one task, from the sweep's seed, the point's index and the wavelength.

    ``numpy.random.SeedSequence`` mixes the three (the wavelength in picometres), so neighbouring
    tasks get unrelated streams. The result is in ``[0, 2**32)``: the fiber routes derive their
    run seeds as ``seed * 1_000_003 + ...`` in int64, which a seed near 2**63 would overflow.

    Examples
    --------
    >>> task_seed(0, 1, 550.0) == task_seed(0, 1, 550.0) != task_seed(0, 2, 550.0)
    True
    """
    ss = np.random.SeedSequence(entropy=int(seed), spawn_key=(int(point_index), int(round(wavelength_nm * 1000))))
    return int(ss.generate_state(1, np.uint32)[0])


def _config_path(config: SimulationConfig) -> str:
    # a config read from a file is re-parsed under its own path: a relative [weave] wif resolves
    return config.source if Path(config.source).is_file() else f"{config.name}.toml"


@dataclass
class SweepSpec:
    """Everything that determines a sweep's numbers, its points and tasks (validated on creation).

    ``target_rel_err``, ``seed`` and ``max_photons`` of None take the config's values, so a spec
    given them explicitly equal to the config's is the same sweep (same :attr:`digest`).
    ``threads`` (per task) does not change results and is not part of the spec.
    """

    config: SimulationConfig
    plan: Plan
    params: list[SweepParameter]
    method: str = "summation"
    target_rel_err: float | None = None
    seed: int | None = None
    max_photons: int | None = None
    measurable_only: bool = False
    threads: int | None = 1
    points: list[SweepPoint] = field(default_factory=list, init=False)

    def __post_init__(self) -> None:
        if self.method not in FABRIC_METHODS:
            raise SweepError(f"--method must be one of {', '.join(FABRIC_METHODS)}, got {self.method!r}")
        if self.target_rel_err is None:
            self.target_rel_err = self.config.target_rel_err
        if self.seed is None:
            self.seed = self.config.seed
        if self.max_photons is None:
            self.max_photons = self.config.max_photons
        n_points = math.prod(len(p.values) for p in self.params)
        n_tasks = n_points * (1 if self.per_point else len(self.plan.wavelengths_nm))
        if n_points > MAX_POINTS or n_tasks > MAX_TASKS:
            grid = " x ".join(str(len(p.values)) for p in self.params)
            raise SweepError(f"--param: {grid} = {n_points:,} points x {len(self.plan.wavelengths_nm)} wavelengths = "
                             f"{n_tasks:,} tasks; a sweep has at most {MAX_POINTS:,} points and {MAX_TASKS:,} "
                             "tasks (each point is a config and a dataset, each task a file): sweep fewer values")
        doc = tomllib.loads(self.config.text)
        for index, values in enumerate(itertools.product(*(p.values for p in self.params))):
            label = ",".join(f"{p.name}={_value_text(v)}" for p, v in zip(self.params, values, strict=True))
            point_doc = copy.deepcopy(doc)
            for p, v in zip(self.params, values, strict=True):
                config_paths.set_value(point_doc, p.path, v)
            try:
                cfg = parse_config(toml_dumps(point_doc), _config_path(self.config),
                                   source=f"{self.config.source} with {label}")
            except ConfigError as exc:
                raise SweepError(f"--param {label}: {exc}") from None
            self.points.append(SweepPoint(index, tuple(values), label, cfg))

    @property
    def wavelengths_nm(self) -> list[float]:
        """The plan's wavelengths, in nm."""
        return [float(w) for w in self.plan.wavelengths_nm]

    @property
    def per_point(self) -> bool:
        """One task per point (all wavelengths) instead of per (point, wavelength).

        The Monte Carlo (``--method mc``), whose run shares its rays, felt or weave mesh and yarn tables across
        the spectrum (one wavelength's task costs nearly what the whole spectrum costs).
        """
        return self.method == "mc"

    def tasks(self) -> list[SweepTask]:
        """Every task, point by point, wavelength by wavelength (:attr:`per_point`: one per point)."""
        assert self.seed is not None   # the config's when not given (__post_init__)
        if self.per_point:
            return [SweepTask(p, None, task_seed(int(self.seed), p.index, 0.0)) for p in self.points]
        return [SweepTask(p, wl, task_seed(int(self.seed), p.index, wl))
                for p in self.points for wl in self.wavelengths_nm]

    def identity(self) -> dict:
        """The parts of the spec that a resumed sweep must share (see :attr:`digest`)."""
        assert self.seed is not None and self.target_rel_err is not None   # set in __post_init__
        return {"config": self.config.sha256, "plan": self.plan.sha256,
                "parameters": [[p.name, p.path, list(p.values)] for p in self.params],
                "method": self.method, "seed": int(self.seed), "target_rel_err": float(self.target_rel_err),
                "max_photons": self.max_photons, "measurable_only": bool(self.measurable_only),
                "wavelengths_nm": self.wavelengths_nm} | ({"tasks": "per point"} if self.per_point else {})

    @property
    def digest(self) -> str:
        """SHA-256 of :meth:`identity` (config and plan by their own SHA-256)."""
        return hashlib.sha256(json.dumps(self.identity(), sort_keys=True).encode()).hexdigest()

    def document(self) -> dict:
        """The ``sweep.json`` document (:mod:`compare.sweep` reads ``parameters`` and ``points``)."""
        import datetime as dt

        return {
            "schema": SCHEMA, "generator": GENERATOR, "digest": self.digest, "identity": self.identity(),
            "config": {"name": self.config.name, "source": self.config.source, "sha256": self.config.sha256},
            "plan": {"name": self.plan.name, "path": str(self.plan.path), "sha256": self.plan.sha256},
            "method": self.method,
            "parameters": [{"name": p.name, "path": p.path, "values": list(p.values)} for p in self.params],
            "points": [{"index": p.index, "dir": p.dir, "label": p.label,
                        "values": {q.name: v for q, v in zip(self.params, p.values, strict=True)}} for p in self.points],
            "wavelengths_nm": self.wavelengths_nm,
            "tasks": len(self.tasks()),
            "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        }
