"""Configs, plans and datasets in and out: what every other function of the API takes or returns.

``load_config`` and ``load_plan`` accept a preset name, a TOML file or an object already loaded;
``read_dataset`` and ``write_dataset`` read and write a dataset folder (``radiance.csv`` and
``meta.json``) under the output rule of every writer (an occupied folder only with ``force``, a run
folder never).
"""

from __future__ import annotations

import os
from pathlib import Path

from fabric_optics import validate as _v
from fabric_optics.errors import InputError, OutputExistsError, typed_errors
from gonio.acquisition.plan import Plan
from gonio.data.dataset import Dataset
from gonio.data.outputs import OutputRefused
from gonio.data.outputs import refuse_existing as _refuse_output
from gonio.data.outputs import refuse_run_folder as _refuse_run_folder
from simulate.config import SimulationConfig

__all__ = ["load_config", "load_plan", "read_dataset", "write_dataset", "as_dataset", "refuse_existing"]


@typed_errors
def load_config(config: str | os.PathLike | SimulationConfig) -> SimulationConfig:
    """A simulation config: a preset, a TOML file, or a config already loaded.

    Every function of the API that models a fabric takes a config in any of these three forms and
    loads it here, so a preset, a file and an object behave alike and are validated once.

    Parameters
    ----------
    config : str, path or SimulationConfig
        A preset name (`"red-cotton"`, `"green-felt"`, `"green-felt-mc"`, ...), the path of a config
        TOML file (docs: config schema), or a config already loaded (returned as is).

    Returns
    -------
    SimulationConfig
        The validated config (`.name`, `.wavelengths_nm`, `.target_rel_err`, ...).

    Raises
    ------
    InputError
        No such preset or file, or a field that is invalid (the message names it).

    Examples
    --------
    >>> import fabric_optics as fo
    >>> cfg = fo.load_config("red-cotton")
    >>> cfg.name, len(cfg.wavelengths_nm) > 0
    ('red-cotton', True)
    """
    from simulate.config import load_config as _load

    if isinstance(config, SimulationConfig):
        return config
    _v.path("config", config)
    return _load(config if isinstance(config, (str, Path)) else Path(config))


@typed_errors
def load_plan(plan: str | os.PathLike | Plan = "red-cotton") -> Plan:
    """An acquisition plan: the geometries to measure (or simulate) and the wavelengths.

    The same plan drives an acquisition and a simulation, so that the two datasets share their
    geometries and wavelengths and can be compared point by point.

    Parameters
    ----------
    plan : str, path or Plan
        A preset name (`"red-cotton"`, `"green-felt"`, ...; docs: plans), the path of a plan TOML
        file, or a plan already loaded (returned as is).

    Returns
    -------
    Plan
        The validated plan; `plan.geometries()` is its table of geometries.

    Raises
    ------
    InputError
        No such preset or file, or a field that is invalid (the message names it).

    Examples
    --------
    >>> import fabric_optics as fo
    >>> plan = fo.load_plan("red-cotton")
    >>> plan.name, sorted(plan.geometries()["theta_i"].unique().tolist())
    ('red-cotton', [0.0, 30.0, 45.0, 60.0])
    """
    from gonio.acquisition.plan import load_plan as _load

    if isinstance(plan, Plan):
        return plan
    _v.path("plan", plan)
    return _load(plan if isinstance(plan, (str, Path)) else Path(plan))


def as_dataset(data: str | os.PathLike | Dataset) -> Dataset:
    """A dataset given as an object or as its folder, read when it is a folder.

    Parameters
    ----------
    data : str, path or Dataset
        A dataset (returned as is) or its folder (read with :func:`read_dataset`).

    Returns
    -------
    Dataset
        The dataset.

    Raises
    ------
    InputError
        No such folder, or a folder that is not a valid dataset.
    """
    return data if isinstance(data, Dataset) else read_dataset(data)


@typed_errors
def read_dataset(path: str | os.PathLike) -> Dataset:
    """Read a radiance-coefficient dataset folder (`radiance.csv` and `meta.json`; docs: dataset format).

    A dataset is the contract between the packages: measured, imported and simulated datasets are
    read alike, checked against the format's schema.

    Parameters
    ----------
    path : str or path
        The dataset folder.

    Returns
    -------
    Dataset
        The dataset: `.table` (pandas), `.meta` (dict), `.name`, `.kind`, `.wavelengths_nm`.

    Raises
    ------
    InputError
        No such folder, or a file that is not a valid dataset (the message names file and field).

    Examples
    --------
    >>> import fabric_optics as fo
    >>> measured = fo.read_dataset("fixtures/analytic/measured_red")
    >>> measured.kind, len(measured) > 0
    ('measured', True)
    """
    from gonio.data.dataset import read_dataset as _read

    _v.path("path", path)
    return _read(path)


@typed_errors
def write_dataset(dataset: Dataset, path: str | os.PathLike, *, force: bool = False) -> Path:
    """Write `dataset` as a dataset folder (`radiance.csv`, `meta.json`), each file atomically.

    The folder is claimed for this writer while it is written (another writer of the same folder is
    refused), and an acquisition's run folder is never written into: its journal is the record of a
    measurement.

    Parameters
    ----------
    dataset : Dataset
        What to write.
    path : str or path
        The folder; created when missing.
    force : bool, default False
        Replace an existing non-empty folder's dataset.

    Returns
    -------
    Path
        The folder written.

    Raises
    ------
    InputError
        `dataset` is not a Dataset, or `path` or `force` is not usable.
    OutputExistsError
        `path` exists and is not empty and `force` is False, or it is an acquisition's run folder.
    OutputBusyError
        Another writer is writing `path` now.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> import fabric_optics as fo
    >>> out = Path(tempfile.mkdtemp()) / "truth"
    >>> fo.write_dataset(fo.truth("lambert:0.5"), out).name
    'truth'
    >>> fo.write_dataset(fo.truth("lambert:0.5"), out)
    Traceback (most recent call last):
    ...
    fabric_optics.api.OutputExistsError: ...the folder is not empty; pass force=True to replace its output, or choose a new folder
    """
    from gonio.data.dataset import write_dataset as _write

    if not isinstance(dataset, Dataset):
        raise InputError(f"dataset: expected a Dataset, got {type(dataset).__name__}")
    out = _v.out_path("path", path)
    _v.flag("force", force)
    with _v.claimed("path", out):
        refuse_existing(out, force, "path", run_folder=True)
        return _write(dataset, out)


def refuse_existing(out: Path, force: bool, what: str = "out", *, ask: str = "force=True",
                     file: bool = False, run_folder: bool = False) -> None:
    """Refuse an output that holds something unless `force` is given (the output rule of every writer).

    The rule is :mod:`gonio.data.outputs`'s: an existing file, or a folder holding anything (hidden
    files aside), is written only with `force`; with `run_folder`, an acquisition's run folder never.

    Parameters
    ----------
    out : Path
        The file or folder about to be written.
    force : bool
        Whether the caller asked to replace what `out` holds.
    what : str, default "out"
        The argument that named `out`, for the message.
    ask : str, default "force=True"
        What the message tells the caller to pass to go ahead.
    file : bool, default False
        `out` is a file (not a folder).
    run_folder : bool, default False
        Refuse an acquisition's run folder even with `force`.

    Raises
    ------
    OutputExistsError
        `out` holds something and `force` is False, or it is a run folder and `run_folder` is True.
    """
    try:
        if run_folder:
            _refuse_run_folder(out, option=what, ask=ask)
        _refuse_output(out, force=force, option=what, ask=ask, file=file)
    except OutputRefused as exc:
        raise OutputExistsError(str(exc)) from None
