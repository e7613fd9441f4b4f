"""Measurements: made on the mock instrument, its true values, or imported from files made elsewhere.

:func:`measure_on_mock` is ``gonio demo``, :func:`truth` is ``gonio truth`` and
:func:`import_measurement` is ``gonio import``; each returns a measured dataset.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from fabric_optics import validate as _v
from fabric_optics.api.loading import load_plan, read_dataset, refuse_existing
from fabric_optics.errors import InputError, OutputExistsError, typed_errors
from gonio.acquisition.plan import Plan
from gonio.data.dataset import Dataset
from gonio.data.formats import FORMATS
from gonio.data.outputs import OutputRefused

__all__ = ["IMPORT_FORMATS", "import_measurement", "measure_on_mock", "truth"]

IMPORT_FORMATS: tuple[str, ...] = tuple(FORMATS)
"""The file formats `import_measurement` reads (`gonio import FORMAT`): `"rgl-bsdf"` (RGL `.bsdf` tensor
files), `"pgii"` (PAB pgII text files, one incidence each), `"merl"` (MERL binary tables)."""
#: the formats a file name tells by its suffix (pgII files have none of their own)
_SUFFIX_FORMATS = {".bsdf": "rgl-bsdf", ".binary": "merl"}


@typed_errors
def measure_on_mock(out: str | os.PathLike, *, sample: str = "red-cotton", plan: str | os.PathLike | Plan | None = None,
                    seed: int = 0, force: bool = False, progress: bool = False) -> Dataset:
    """Measure a plan on the embedded mock goniophotometer, through the real driver and protocols (`gonio demo`).

    The mock serves Modbus TCP and a serial line on loopback; the driver calibrates against the
    white standard and measures every point of the plan, writing the run's journal and the
    dataset into `out`.

    Parameters
    ----------
    out : str or path
        The run folder (journal and dataset).
    sample : str, default "red-cotton"
        What the mock holds: `"red-cotton"` (an analytic stand-in with the published colour of red
        cotton), `"lambert:RHO"`, a dataset folder, or an RGL `.bsdf` file such as
        `fixtures/real/acrylic_felt_green_rgb.bsdf`.
    plan : str, path or Plan, optional
        The plan; by default the red-cotton plan's geometry, named after the sample.
    seed : int, default 0
        Seed of the mock's noise.
    force : bool, default False
        Replace an earlier demo's folder (another acquisition's run folder is never replaced).
    progress : bool, default False
        Show a progress bar.

    Returns
    -------
    Dataset
        The measured dataset, as written in `out`.

    Raises
    ------
    OutputExistsError
        `out` holds an earlier output and `force` is False, or holds another acquisition's run.
    OutputBusyError
        Another writer is writing `out` now.
    InputError
        An unknown sample or plan, or a seed out of range.

    Examples
    --------
    The `quick` plan is the shortest (the mock's settle times are real: the red-cotton plan's
    time is in docs/tutorials/python.md):

    >>> import tempfile
    >>> from pathlib import Path
    >>> import fabric_optics as fo
    >>> out = Path(tempfile.mkdtemp()) / "measured"
    >>> measured = fo.measure_on_mock(out, sample="red-cotton", plan="quick")
    >>> measured.kind, len(measured), (out / "radiance.csv").is_file()
    ('measured', 36, True)
    """
    from gonio.demo import run_demo
    from gonio.mock.samples import SampleError

    out = _v.out_path("out", out)
    _v.text("sample", sample, max_len=4096)
    _v.integer("seed", seed, 0, _v.MAX_SEED)
    _v.flag("force", force)
    _v.flag("progress", progress)
    plan_obj = load_plan("red-cotton" if plan is None else plan)
    with _v.claimed("out", out):
        try:
            run_demo(out, plan_obj, seed=seed, force=force, progress=progress, sample=sample,
                     name_from_sample=plan is None and sample != "red-cotton")
        except SampleError as exc:
            raise InputError(f"sample {sample!r}: {exc}") from exc
        except OutputRefused as exc:
            raise OutputExistsError(str(exc)) from exc
    return read_dataset(out)


@typed_errors
def truth(sample: str, plan: str | os.PathLike | Plan = "red-cotton") -> Dataset:
    """The mock sample's true radiance coefficient at a plan's geometries (`gonio truth`).

    This is what a perfect measurement of the sample gives: the reference an acquisition on the
    mock instrument is checked against.

    Parameters
    ----------
    sample : str
        A mock sample, as `measure_on_mock` takes it.
    plan : str, path or Plan, default "red-cotton"
        The geometries and wavelengths.

    Returns
    -------
    Dataset
        The sample's values, without instrument noise.

    Raises
    ------
    InputError
        An unknown sample or plan.

    Examples
    --------
    >>> import fabric_optics as fo
    >>> truth = fo.truth("lambert:0.5", plan="red-cotton")
    >>> float(truth.table["beta"].min()), float(truth.table["beta"].max())
    (0.5, 0.5)
    """
    from gonio.mock.samples import SampleError
    from gonio.mock.truth import truth_dataset

    _v.text("sample", sample, max_len=4096)
    try:
        return truth_dataset(sample, load_plan(plan))
    except SampleError as exc:
        raise InputError(f"sample {sample!r}: {exc}") from exc


@typed_errors
def import_measurement(path: str | os.PathLike | Sequence[str | os.PathLike], out: str | os.PathLike | None = None,
                       *, force: bool = False, format: str | None = None, plan: str | os.PathLike | Plan | None = None,
                       scale: float | None = None, white: str | os.PathLike | None = None,
                       white_reflectance: float = 0.99, keep_grazing: bool = False) -> Dataset:
    """Import a measurement made elsewhere as a radiance-coefficient dataset (`gonio import`).

    The imported dataset is in the project's own format, so that it is simulated, compared and
    fitted like a measurement made with the instrument.

    Parameters
    ----------
    path : str, path, or a sequence of them
        The file, or the files of one measurement (pgII: one file per incidence).
    out : str or path, optional
        Also write the dataset into this folder (as `gonio import --out` does).
    force : bool, default False
        Replace what `out` holds.
    format : str, optional
        One of `IMPORT_FORMATS`: `"rgl-bsdf"` (RGL `.bsdf` tensor files, RGB or spectral), `"pgii"`
        (PAB pgII text files) or `"merl"` (MERL `.binary` tables). Inferred from a `.bsdf` or
        `.binary` suffix; required for pgII files.
    plan : str, path or Plan, optional
        For the tabulated formats (rgl-bsdf, merl): evaluate the file at this plan's geometries;
        `"measured"` (rgl-bsdf only): the file's own measured incidences and its retro-reflection
        rings. By default in-plane curves (at an RGL file's own incidences).
    scale : float, optional
        pgII files in detector current (uA): f_r per uA, making absolute values; without it (and
        without `white`) the dataset is relative.
    white : str or path, optional
        pgII: a pgII file of a diffuse white standard measured with the same detector (absolute values).
    white_reflectance : float, default 0.99
        The hemispherical reflectance of that standard.
    keep_grazing : bool, default False
        Keep incidences at 89 deg and beyond (the RGL files' last node is an extrapolation; dropped
        with a note by default).

    Returns
    -------
    Dataset
        The imported dataset (RGB files give a dataset with a `channel` column).

    Raises
    ------
    InputError
        An unknown or uninferable format, a malformed file (the message names file and line or
        offset), a non-positive `scale`, a `white_reflectance` outside (0, 1].
    OutputExistsError
        `out` holds something and `force` is False.
    OutputBusyError
        Another writer is writing `out` now.

    Examples
    --------
    The real green felt of the RGL database, at its own incidences:

    >>> import fabric_optics as fo
    >>> felt = fo.import_measurement("fixtures/real/acrylic_felt_green_rgb.bsdf")
    >>> felt.is_rgb, sorted(felt.table["channel"].unique())
    (True, ['B', 'G', 'R'])
    """
    from gonio.acquisition.plan import MEASURED, measured_plan
    from gonio.data.formats import import_files

    if isinstance(path, (str, os.PathLike)):
        paths = [_v.path("path", path)]
    elif isinstance(path, (list, tuple)) and 0 < len(path) <= 1000:
        paths = [_v.path(f"path[{k}]", p) for k, p in enumerate(path)]
    else:
        raise InputError(f"path={path!r}: give a file or a list of 1 to 1000 files")
    if format is not None:
        _v.choice("format", format, IMPORT_FORMATS)
    _v.number("scale", scale, 0.0, lo_open=True, none=True)
    _v.number("white_reflectance", white_reflectance, 0.0, 1.0, lo_open=True)
    _v.path("white", white, none=True)
    _v.flag("force", force)
    _v.flag("keep_grazing", keep_grazing)
    if out is not None:
        _v.out_path("out", out)
    fmt = format if format is not None else _SUFFIX_FORMATS.get(Path(paths[0]).suffix.lower())
    if fmt is None:
        raise InputError(f"format: cannot tell the format of {paths[0]} from its name; pass format= one of "
                         f"{', '.join(IMPORT_FORMATS)}")
    if fmt not in IMPORT_FORMATS:
        raise InputError(f"format {fmt!r}: choose one of {', '.join(IMPORT_FORMATS)}")
    geometries = None
    if plan is not None:
        if plan == MEASURED:
            if not (str(paths[0]).endswith(".bsdf") and Path(paths[0]).is_file()):
                raise InputError(f"plan {MEASURED!r}: follows the measured incidences of an RGL .bsdf file, but "
                                 f"{paths[0]} is not one; give a .bsdf file or a plan")
            geometries = measured_plan(Path(paths[0])).geometries(measurable_only=True)
        else:
            geometries = load_plan(plan).geometries()
    if out is None:
        return import_files(fmt, paths, geometries, scale=scale, white=white, white_reflectance=white_reflectance,
                            keep_grazing=keep_grazing)
    out_dir = _v.out_path("out", out)
    with _v.claimed("out", out_dir):     # one writer of the dataset's folder, from its check to its last rename
        refuse_existing(out_dir, force)
        dataset = import_files(fmt, paths, geometries, scale=scale, white=white,
                               white_reflectance=white_reflectance, keep_grazing=keep_grazing)
        from gonio.data.dataset import write_dataset as _write
        from gonio.data.outputs import WRITTEN_BY

        dataset.meta[WRITTEN_BY] = "gonio import"
        _write(dataset, out_dir)
    return dataset
