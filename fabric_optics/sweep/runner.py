r"""``simulate sweep``: parameter studies of a fabric model on dask.distributed.

``simulate sweep CONFIG [MEASURED] --param NAME=v1,v2,... [--param NAME2=...] --out DIR [--method summation|classic|mc]
[--plan PLAN] [--scheduler tls://HOST:PORT [--tls-ca-file F --tls-cert F --tls-key F]] [--workers N] [--resume]``

Parameters, points and their limits: :mod:`fabric_optics.sweep.spec`.

Tasks and seeds
---------------
One task per (parameter point, wavelength of the plan): :func:`evaluate_task` runs
:func:`simulate.virtual.fabric_dataset` on a one-wavelength copy of the plan. That granularity
spreads a sweep over as many workers as it has tasks, at the price of the work a full-spectrum
run shares between wavelengths (the classic model's one walk), which each task redoes for its
wavelength. The Monte Carlo (``--method mc``) is the exception: one task per point, all
wavelengths (``tasks/p003.npz``; :attr:`~fabric_optics.sweep.spec.SweepSpec.per_point`) -- its run shares
everything across the spectrum (rays, the felt or weave mesh, the yarn tables walked once for all
wavelengths: a per-wavelength task would cost nearly what the whole spectrum costs), and its
accuracy control then holds the one relative error of ``simulate fabric`` itself.

Accuracy: ``--target-rel-err`` means what it means for ``simulate fabric`` (the one relative
error, :func:`simulate.montecarlo.accuracy.relative_error`: RMS of ``u`` relative to each
direction's spectral PEAK), but a task sees one wavelength, so its own control can only hold
``u`` to the target relative to that wavelength's value. That is never looser than the peak
definition (a value is at most its spectrum's peak) and costs more photons at dark, dye-absorbed
wavelengths. What a sweep REPORTS is the one definition: ``rel_err`` of each point's assembled
spectra (``summary.csv``, ``provenance.rel_err``), comparable with ``simulate fabric``'s.

Each task's seed is :func:`task_seed` of (the sweep's seed,
the point's index, the wavelength), independent of which worker runs it and when, so a sweep
gives the same numbers, byte for byte, on 1 or 20 workers and in any completion order. The
points get independent seeds (not common random numbers): each point's Monte Carlo error is
then an honest, independent sample, as a user reading one point's dataset expects.

Storage, resume and failures
----------------------------
``DIR/sweep.json`` is written first: the spec (config, plan, parameters, method, seed,
accuracy, wavelengths, points) and its digest. Each finished task's result is stored by the
client (not the worker: remote workers need no shared file system) in ``DIR/tasks/<task>.npz``
(``p003_w0550.npz``: point 3, 550 nm), atomically (temporary file in ``DIR/tasks``, fsync,
rename), as soon as it arrives. A sweep run again into the same ``DIR`` with the same spec --
``--resume`` says so explicitly -- submits only the tasks without a file: a killed sweep
recomputes nothing it had stored. A different spec in an existing sweep directory is refused
(exit 2, naming what differs), and a non-empty ``--out`` that is not a sweep directory is never
written into. A lock (``flock`` on ``DIR/.sweep.lock``) keeps a second sweep out of a running one.

A task that raises is retried by dask (``retries``, default 2); one that still fails is reported
(one line per task) and the sweep exits 1 at the end, after storing every task that finished
and assembling every point whose tasks are all there.

Outputs
-------
``DIR/points/<name>=<value>[,<name2>=<value2>]/``: one radiance-coefficient dataset per
complete point (:func:`gonio.data.dataset.write_dataset`), assembled from the task files only
(so a resumed sweep writes what an uninterrupted one writes); its ``meta.json`` records the
parameter values under ``provenance.sweep``. ``DIR/summary.csv``: one row per point (parameter
values, status, tasks done, compute seconds summed over its tasks, ``rel_err`` as defined above, and
with ``measured`` the ``compare`` figures NRMSE, hue and saturation difference). ``compare
report MEASURED DIR --out R`` charts those against the parameter (:mod:`compare.sweep`).
"""

from __future__ import annotations

import dataclasses
import fcntl
import io
import json
import logging
import math
import os
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from fabric_optics.sweep.spec import (
    GENERATOR,
    LOCK_NAME,
    POINTS_DIR,
    SCHEMA,
    SUMMARY_NAME,
    SWEEP_NAME,
    TASKS_DIR,
    SweepError,
    SweepParameter,
    SweepPoint,
    SweepSpec,
    SweepTask,
    parse_params,
    task_seed,
)
from fabric_optics.sweep.spec import (
    point_dir as _point_dir,
)
from gonio.acquisition.plan import Plan
from gonio.data.dataset import COLUMNS, Dataset, atomic_write, make_dataset, new_meta
from gonio.data.outputs import occupied
from simulate.config import SimulationConfig
from simulate.montecarlo.accuracy import REL_ERR_DEFINITION, relative_error
from simulate.outdir import OutputError, recover_all, write_dataset_dir
from simulate.provenance import jsonable, software_versions
from simulate.virtual import fabric_dataset

__all__ = [
    "GENERATOR",
    "SCHEMA",
    "SUMMARY_NAME",
    "SWEEP_NAME",
    "SweepError",
    "SweepParameter",
    "SweepPoint",
    "SweepResult",
    "SweepSpec",
    "SweepTask",
    "TaskArgs",
    "evaluate_task",
    "finished_tasks",
    "parse_params",
    "prepare_out",
    "clear_sweep",
    "run_sweep",
    "task_seed",
]

log = logging.getLogger(__name__)

#: temporary files of :func:`gonio.data.dataset.atomic_write` for a task file (a killed write)
_TEMP_NAME = re.compile(r"\.p\d+_w[0-9p]+\.npz\.[a-z0-9_]{8}\.tmp")


# ------------------------------------------------------------------------------------------
# the task (runs on a worker)


@dataclass(frozen=True)
class TaskArgs:
    """What a worker needs for one task (pickled to it; it writes nothing)."""

    task_id: str
    config: SimulationConfig
    plan: Plan
    wavelength_nm: float | None
    seed: int
    method: str
    target_rel_err: float
    max_photons: int | None
    measurable_only: bool
    threads: int | None


def evaluate_task(args: TaskArgs) -> dict:
    """Evaluate one point's model at one wavelength (or all: ``wavelength_nm`` None).

    Returns ``{"columns": {...}, "meta": {...}}``.

    The plan is copied with only ``args.wavelength_nm`` (the dye is sampled exactly there).
    """
    started = time.perf_counter()
    plan = args.plan if args.wavelength_nm is None else \
        dataclasses.replace(args.plan, wavelengths_nm=np.array([args.wavelength_nm], float))
    ds = fabric_dataset(args.config, plan, args.method, target_rel_err=args.target_rel_err, seed=args.seed,
                        threads=args.threads, max_photons=args.max_photons, measurable_only=args.measurable_only)
    meta = jsonable(ds.meta)
    meta["provenance"]["task"] = {"id": args.task_id, "seed": args.seed,
                                  "seconds": time.perf_counter() - started, "worker_pid": os.getpid()}
    return {"columns": {c: ds.table[c].to_numpy() for c in COLUMNS}, "meta": meta}


# ------------------------------------------------------------------------------------------
# the sweep directory


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def clear_sweep(out: Path) -> None:
    """Remove a previous sweep's own files from ``out``, nothing else (``simulate sweep --force``)."""
    if not (out / SWEEP_NAME).is_file():
        return
    try:
        for name in (TASKS_DIR, POINTS_DIR):
            if (out / name).is_dir():
                shutil.rmtree(out / name)
        for name in (SUMMARY_NAME, SWEEP_NAME):
            (out / name).unlink(missing_ok=True)
    except OSError as exc:
        raise SweepError(f"--out {out}: cannot remove the previous sweep ({exc.strerror})") from None


def prepare_out(out: Path, spec: SweepSpec, resume: bool = False) -> bool:
    """Check that ``out`` may receive ``spec``'s sweep; write ``sweep.json`` when it is new.

    Returns True when ``out`` already holds this sweep (a resume). Raises :class:`SweepError`
    for a file, a non-empty directory that is not a sweep, a sweep of a different spec (naming
    the parts that differ), or ``resume`` without a sweep to resume.
    """
    if out.exists() and not out.is_dir():
        raise SweepError(f"--out {out}: exists and is not a directory; choose a directory path")
    previous = out / SWEEP_NAME
    if out.is_dir() and previous.exists():
        doc = _read_json(previous)
        if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
            raise SweepError(f"--out {out}: {SWEEP_NAME} is not a readable sweep description; "
                             "remove the directory or choose a new --out")
        if doc.get("digest") != spec.digest:
            identity = doc.get("identity")
            old = identity if isinstance(identity, dict) else {}
            new = spec.identity()
            differ = [k for k in new if old.get(k) != new[k]] or ["the spec"]
            raise SweepError(f"--out {out}: holds a different sweep ({', '.join(differ)} differ); remove that "
                             "directory or choose a new --out")
        return True
    if resume:
        raise SweepError(f"--resume: {out} holds no sweep ({SWEEP_NAME} is missing); run without --resume to "
                         "start one")
    if out.is_dir():
        try:
            full = occupied(out)
        except OSError as exc:
            raise SweepError(f"--out {out}: cannot read the directory ({exc.strerror})") from None
        if full:
            raise SweepError(f"--out {out}: directory is not empty and is not a sweep directory (no {SWEEP_NAME}); "
                             "refusing to write into it (choose a new or empty directory)")
    try:
        (out / TASKS_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SweepError(f"--out {out}: cannot create the directory ({exc.strerror})") from None
    _write(previous, (json.dumps(spec.document(), indent=1) + "\n").encode("utf-8"))
    return False


class _Lock:
    """``flock`` on ``DIR/.sweep.lock`` for one run (released by the kernel if the process dies)."""

    def __init__(self, out: Path):
        self.fd = os.open(out / LOCK_NAME, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(self.fd)
            raise SweepError(f"--out {out}: another `simulate sweep` is running in this directory") from None

    def release(self) -> None:
        fcntl.flock(self.fd, fcntl.LOCK_UN)
        os.close(self.fd)


def _task_path(out: Path, task: SweepTask) -> Path:
    return out / TASKS_DIR / f"{task.id}.npz"


def _write_task(out: Path, spec: SweepSpec, task: SweepTask, result: dict) -> None:
    buffer = io.BytesIO()
    arrays: dict[str, Any] = {c: np.asarray(v) for c, v in result["columns"].items()}
    arrays.update(digest=np.array(spec.digest), meta=np.array(json.dumps(result["meta"])))
    np.savez(buffer, **arrays)
    _write(_task_path(out, task), buffer.getvalue())


def _write(path: Path, data: bytes) -> None:
    """:func:`atomic_write` whose failure (a full disk) is one :class:`SweepError` naming the file."""
    try:
        atomic_write(path, data)
    except OSError as exc:
        raise SweepError(f"{path}: cannot write ({exc.strerror or exc}); the file was left as it was and the "
                         "finished tasks are kept (free some space, then run the same command again)") from None


def _read_task(path: Path) -> tuple[str, pd.DataFrame, dict]:
    with np.load(path, allow_pickle=False) as z:
        table = pd.DataFrame({c: z[c] for c in COLUMNS})
        return str(z["digest"]), table, json.loads(str(z["meta"]))


def finished_tasks(out: Path, spec: SweepSpec) -> set[str]:
    """Ids of ``spec``'s tasks whose files in ``out/tasks`` hold this sweep's results.

    Temporary files of a killed write are removed first; a task file of another spec (or an
    unreadable one) does not count and is overwritten when its task is computed.
    """
    folder = out / TASKS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    for entry in os.scandir(folder):
        if _TEMP_NAME.fullmatch(entry.name) and entry.is_file(follow_symlinks=False):
            os.unlink(entry.path)
    done = set()
    for task in spec.tasks():
        path = _task_path(out, task)
        if not path.is_file():
            continue
        try:
            digest, _, _ = _read_task(path)
        except (OSError, ValueError, KeyError) as exc:
            log.warning("%s is unreadable (%s): the task is computed again", path, exc)
            continue
        if digest == spec.digest:
            done.add(task.id)
        else:
            log.warning("%s belongs to another sweep: the task is computed again", path)
    return done


# ------------------------------------------------------------------------------------------
# running


@dataclass
class SweepResult:
    """What :func:`run_sweep` did: the summary rows, failures (``task id -> line``), counts."""

    summary: pd.DataFrame
    failures: dict[str, str]
    computed: int
    reused: int
    seconds: float


def _task_args(spec: SweepSpec, task: SweepTask) -> TaskArgs:
    assert spec.target_rel_err is not None   # the config's when not given (SweepSpec.__post_init__)
    return TaskArgs(task.id, task.point.config, spec.plan, task.wavelength_nm, task.seed, spec.method,
                    float(spec.target_rel_err), spec.max_photons, spec.measurable_only, spec.threads)


def run_sweep(spec: SweepSpec, out: Path, client: Any, *, retries: int = 2, progress: bool = False,
              measured: Dataset | None = None) -> SweepResult:
    """Run the tasks of ``spec`` without a file in ``out`` on the dask ``client``, then assemble.

    ``out`` must have been prepared by :func:`prepare_out`. ``client`` is a
    ``distributed.Client`` (any cluster) or None when every task is already stored. Results are
    written as they complete; on KeyboardInterrupt the pending tasks are cancelled and the
    interrupt re-raised (everything stored so far stays). ``measured`` adds the ``compare``
    figures to the summary.
    """
    from tqdm import tqdm

    started = time.perf_counter()
    lock = _Lock(out)
    try:
        done = finished_tasks(out, spec)
        todo = [t for t in spec.tasks() if t.id not in done]
        failures: dict[str, str] = {}
        if todo:
            from distributed import as_completed

            if client is None:
                raise ValueError(f"{len(todo)} tasks to compute and no dask client")

            short = spec.digest[:8]
            futures = {client.submit(evaluate_task, _task_args(spec, t), key=f"sweep-{short}-{t.id}",
                                     retries=retries, pure=False): t for t in todo}
            bar = tqdm(total=len(done) + len(todo), initial=len(done), desc="sweep", unit="task",
                       disable=not progress, leave=False)
            try:
                for future in as_completed(futures):
                    task = futures[future]
                    if future.status == "finished":
                        _write_task(out, spec, task, future.result())
                    else:
                        failures[task.id] = _failure_line(task, future, retries)
                        bar.set_postfix(failed=len(failures))
                    future.release()
                    bar.update(1)
            except BaseException:
                client.cancel(list(futures))
                raise
            finally:
                bar.close()
        summary = assemble(out, spec, measured)
        return SweepResult(summary, failures, computed=len(todo) - len(failures), reused=len(done),
                           seconds=time.perf_counter() - started)
    finally:
        lock.release()


def _failure_line(task: SweepTask, future: Any, retries: int) -> str:
    try:
        exc = future.exception()
        what = f"{type(exc).__name__}: {exc}".splitlines()[0] if exc is not None else future.status
    except Exception as err:  # a cancelled future (lost scheduler) has no exception to fetch
        what = f"{future.status} ({type(err).__name__})"
    return (f"task {task.id} ({task.point.label}, {task.what}) failed after {retries + 1} "
            f"attempt(s): {what}")


# ------------------------------------------------------------------------------------------
# assembling the points


def _task_key(task: SweepTask) -> str:
    return "all" if task.wavelength_nm is None else f"{task.wavelength_nm:g}"


def _point_dataset(out: Path, spec: SweepSpec, point: SweepPoint, tasks: list[SweepTask]) -> Dataset:
    tables, metas = [], []
    for task in tasks:
        _, table, meta = _read_task(_task_path(out, task))
        tables.append(table)
        metas.append(meta)
    table = pd.concat(tables, ignore_index=True)
    first = metas[0]
    provs = [m["provenance"] for m in metas]
    photons = [p.get("photons") for p in provs]
    geometry = ["theta_i", "phi_i", "theta_o", "phi_o"]
    spectra = table.set_index(geometry + ["wavelength_nm"])[["beta", "u_beta"]].unstack("wavelength_nm")
    values = {p.name: v for p, v in zip(spec.params, point.values, strict=True)}
    assert spec.seed is not None   # the config's when not given (SweepSpec.__post_init__)
    prov = dict(first["provenance"])
    prov.pop("task", None)
    prov.update({
        "command": GENERATOR,
        "config": point.config.provenance(),
        "seed": int(spec.seed),
        "task_seeds": {_task_key(t): t.seed for t in tasks},
        # the one definition over the assembled spectra ([geometry, wavelength]), not per task
        "rel_err": relative_error(spectra["beta"].to_numpy(float), spectra["u_beta"].to_numpy(float)),
        "rel_err_definition": REL_ERR_DEFINITION,
        "photons": None if any(n is None for n in photons) else int(sum(photons)),
        "seconds": float(sum(p["task"]["seconds"] for p in provs)),
        "fiber_seconds": float(sum(p.get("fiber_seconds") or 0.0 for p in provs)),
        "fiber_info": {_task_key(t): p.get("fiber_info") for t, p in zip(tasks, provs, strict=True)},
        "sweep": {"parameters": values, "paths": {p.name: p.path for p in spec.params}, "point": point.index,
                  "digest": spec.digest},
        "versions": software_versions(),
    })
    sample = dict(first["sample"])
    sample["name"] = f"{sample.get('name', spec.plan.name)}; {point.label}"
    model = dict(first["model"])
    model["generator"] = GENERATOR
    if spec.method == "classic":
        model["rho_d"] = [x for m in metas for x in m["model"].get("rho_d", [])]
        model["u_rho_d"] = [x for m in metas for x in m["model"].get("u_rho_d", [])]
    return make_dataset(table, new_meta("simulated", sample, model, prov))


def assemble(out: Path, spec: SweepSpec, measured: Dataset | None = None) -> pd.DataFrame:
    """Write the dataset of every complete point and ``summary.csv``; return the summary.

    Columns: ``point``, ``dir``, one per parameter, ``status`` (``complete`` or ``incomplete``),
    ``tasks_done``, ``tasks``, ``seconds`` (compute time summed over the point's tasks),
    ``rel_err`` (:func:`simulate.montecarlo.accuracy.relative_error` of the point's assembled
    spectra) and, with ``measured``, ``nrmse``, ``dh``, ``ds``
    (:func:`compare.sweep.point_metrics`; NaN when the comparison is refused, logged).
    """
    rows = []
    try:
        recover_all(out / POINTS_DIR)       # folders of a killed assembly (simulate.outdir), one scan
    except OSError as exc:
        raise SweepError(f"{out / POINTS_DIR}: cannot clean up after a killed run ({exc.strerror})") from None
    by_point: dict[int, list[SweepTask]] = {}
    for task in spec.tasks():
        by_point.setdefault(task.point.index, []).append(task)
    for point in spec.points:
        tasks = by_point[point.index]
        n_done = sum(_task_path(out, t).is_file() for t in tasks)
        row: dict[str, Any] = {"point": point.index, "dir": point.dir}
        row.update({p.name: v for p, v in zip(spec.params, point.values, strict=True)})
        row.update(status="complete" if n_done == len(tasks) else "incomplete", tasks_done=n_done,
                   tasks=len(tasks), seconds=math.nan, rel_err=math.nan)
        if measured is not None:
            row.update(nrmse=math.nan, dh=math.nan, ds=math.nan)
        if n_done == len(tasks):
            ds = _point_dataset(out, spec, point, tasks)
            try:
                write_dataset_dir(ds, _point_dir(out, point.dir), recovered=True)
            except OutputError as exc:
                raise SweepError(f"{exc} (the finished tasks are kept; run the same command again)") from None
            prov = ds.meta["provenance"]
            row.update(seconds=prov["seconds"], rel_err=prov["rel_err"])
            if measured is not None:
                row.update(_metrics(measured, ds, point))
        rows.append(row)
    summary = pd.DataFrame(rows)
    _write(out / SUMMARY_NAME, summary.to_csv(index=False, float_format="%.10g", lineterminator="\n")
                 .encode("utf-8"))
    return summary


def _metrics(measured: Dataset, ds: Dataset, point: SweepPoint) -> dict:
    from compare.errors import CompareError
    from compare.sweep import point_metrics

    try:
        return point_metrics(measured, ds)
    except CompareError as exc:
        log.warning("point %s: no comparison with the measurement: %s", point.label, exc)
        return {}
