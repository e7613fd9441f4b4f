"""``simulate sweep``: a parameter study on dask.distributed, one dataset per point and summary.csv.

The client is a local cluster or a named scheduler, both behind TLS (:mod:`fabric_optics.sweep.cluster`);
the work is :func:`fabric_optics.sweep.runner.run_sweep`; exit 1 when a task still fails after its retries.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from fabric_optics import api
from fabric_optics.cli.common import (
    UsageError,
    add_force,
    add_no_progress,
    add_plan,
    add_seed,
    add_target_rel_err,
    add_threads,
    int_in,
    progress,
)
from fabric_optics.cli.simulate.options import (
    check_cost,
)

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``simulate sweep``."""
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name, e.g. red-cotton)")
    p.add_argument("measured", metavar="MEASURED", type=Path, nargs="?", default=None,
                   help="measured dataset (optional, right after CONFIG): add compare's NRMSE, dh and ds of every point "
                        "to summary.csv")
    p.add_argument("--param", action="append", required=True, metavar="NAME=v1,v2,...",
                   help="a swept config field (dotted path or alias volume_fraction, radius, rms_slope) and its "
                        "values; repeat for a grid (every combination)")
    p.add_argument("--out", type=Path, required=True,
                   help="sweep directory (sweep.json, tasks/, points/<name>=<value>/, summary.csv)")
    add_force(p, "an existing --out sweep (computed afresh; --resume continues it instead)")
    p.add_argument("--method", choices=("summation", "classic", "mc"), default="summation",
                   help="fabric model (default summation)")
    add_plan(p, what="whose geometries and wavelengths are simulated")
    p.add_argument("--measurable-only", action="store_true", dest="measurable_only",
                   help="skip the plan's beam-blocked geometries as the measurement does")
    p.add_argument("--scheduler", metavar="tls://HOST:PORT", default=None,
                   help="address of a running dask scheduler (default: a local cluster of --workers processes, "
                        "behind TLS with temporary credentials)")
    p.add_argument("--tls-ca-file", default=None, dest="tls_ca_file", metavar="FILE",
                   help="--scheduler: CA certificate (PEM); without the three TLS files dask's "
                        "distributed.comm.tls configuration applies")
    p.add_argument("--tls-cert", default=None, dest="tls_cert", metavar="FILE",
                   help="--scheduler: client certificate (PEM)")
    p.add_argument("--tls-key", default=None, dest="tls_key", metavar="FILE",
                   help="--scheduler: client private key (PEM)")
    p.add_argument("--workers", type=int_in(1, 1024), default=None,
                   help="local cluster: worker processes, one thread each (default: the number of CPUs)")
    add_threads(p, default=1, note=" per task: the workers are the parallelism")
    p.add_argument("--retries", type=int_in(0, 100), default=2,
                   help="retries of a failing task before it is reported (default 2)")
    p.add_argument("--resume", action="store_true",
                   help="continue the sweep in --out (it must hold the same sweep)")
    add_target_rel_err(p)
    p.add_argument("--max-photons", type=int_in(1, 10**15), default=None, dest="max_photons", metavar="N",
                   help="photon budget per task (default: the config's; none)")
    add_seed(p, what="sweep seed; each task's seed is derived from it, the point and the wavelength")
    add_no_progress(p)


def _sweep_client(args: argparse.Namespace) -> tuple[Any, Any]:
    """``(client, cluster)``: a client of the named scheduler (cluster None) or of a new local cluster.

    Both behind TLS (:mod:`fabric_optics.sweep.cluster`): a local cluster with temporary credentials, a named
    scheduler with the user's certificates.
    """
    from fabric_optics.sweep.cluster import ClusterError, local_cluster, remote_client

    try:
        if args.scheduler:
            return remote_client(args.scheduler, ca_file=args.tls_ca_file, cert=args.tls_cert,
                                 key=args.tls_key), None
        if args.tls_ca_file or args.tls_cert or args.tls_key:
            raise ClusterError("--tls-ca-file/--tls-cert/--tls-key go with --scheduler (a local cluster makes "
                               "its own temporary credentials)")
        return local_cluster(args.workers or os.cpu_count() or 1)
    except ClusterError as exc:
        raise UsageError(str(exc)) from None


def _check_sweep_cost(args: argparse.Namespace, spec: Any) -> None:
    """:func:`check_cost` of the costliest of up to 9 evenly spaced points, times the points per worker."""
    from simulate.budget import estimate_cost

    wl, target = spec.wavelengths_nm, float(spec.target_rel_err)
    sample = spec.points[::max(1, len(spec.points) // 8)]
    worst = max(sample, key=lambda p: estimate_cost(p.config, wl, target, spec.max_photons).seconds)
    workers = 1 if args.scheduler else (args.workers or os.cpu_count() or 1)
    check_cost("sweep", worst.config, wl, target, spec.max_photons, runs=max(1, -(-len(spec.points) // workers)))


def _sweep_spec(args: argparse.Namespace) -> tuple[Any, Any]:
    """The sweep's spec from the arguments, its cost checked, and the measurement to compare each point with."""
    from fabric_optics.sweep.runner import SweepError, SweepSpec, parse_params

    config = api.load_config(args.config)
    try:
        plan = api.load_plan(args.plan)
    except api.InputError as exc:
        raise UsageError(f"--plan: {exc}") from None
    try:
        spec = SweepSpec(config, plan, parse_params(args.param, config), method=args.method,
                         target_rel_err=args.target_rel_err, seed=args.seed, max_photons=args.max_photons,
                         measurable_only=args.measurable_only, threads=args.threads)
    except SweepError as exc:
        raise UsageError(str(exc)) from None
    _check_sweep_cost(args, spec)
    measured = None
    if args.measured is not None:
        try:
            measured = api.read_dataset(args.measured)
        except api.InputError as exc:
            raise UsageError(f"MEASURED: {exc}") from None
    return spec, measured


def _sweep_folder(args: argparse.Namespace, spec: Any) -> bool:
    """Prepare the sweep's folder (cleared with ``--force``); whether it resumes a sweep already there."""
    from fabric_optics.sweep.runner import SweepError, clear_sweep, prepare_out

    try:
        if args.force and not args.resume:
            clear_sweep(args.out)
        resumed = prepare_out(args.out, spec, resume=args.resume)
    except SweepError as exc:
        raise UsageError(str(exc)) from None
    if resumed and not args.resume:
        raise UsageError(f"--out {args.out}: holds this sweep already; pass --resume to continue it (finished "
                          "tasks are reused) or --force to compute it afresh")
    return resumed


def _print_sweep(args: argparse.Namespace, spec: Any, result: Any, n_tasks: int, resumed: bool) -> None:
    """Print each point's status and figures, the failures, and the line naming what was written."""
    summary = result.summary
    names = [p.name for p in spec.params]
    for row in summary.to_dict("records"):
        figures = f"{row['seconds']:.1f} s, rel_err {row['rel_err']:.2%}"
        if "nrmse" in row:
            figures += f", NRMSE {row['nrmse']:.4g}, dh {row['dh']:+.4f}, ds {row['ds']:+.4f}"
        values = ", ".join(f"{n}={row[n]:g}" for n in names)
        print(f"  {values}: {row['status']}" + (f" ({figures})" if row["status"] == "complete" else
                                                 f" ({row['tasks_done']} of {row['tasks']} tasks)"))
    for line in result.failures.values():
        print(f"simulate sweep: {line}", file=sys.stderr)
    shape = (f"{len(spec.points)} points (all {len(spec.wavelengths_nm)} wavelengths a task)" if spec.per_point else
             f"{len(spec.points)} points x {len(spec.wavelengths_nm)} wavelengths")
    print(f"wrote {args.out} ({shape} = {n_tasks} tasks: "
          f"{result.computed} computed, {result.reused} reused{', resumed' if resumed else ''}, "
          f"{len(result.failures)} failed; summary in {args.out / 'summary.csv'})")


def run(args: argparse.Namespace) -> int:
    """``simulate sweep``: the spec, the folder, the tasks on the cluster, then the points' summary."""
    from fabric_optics.sweep.runner import SweepError, finished_tasks, run_sweep

    spec, measured = _sweep_spec(args)
    resumed = _sweep_folder(args, spec)
    if not args.verbose:
        # distributed's own logs (cluster start/stop, each failed attempt's traceback, in the
        # workers too: they inherit the environment) are not for users; failures are reported below
        os.environ["DASK_LOGGING__DISTRIBUTED"] = "critical"
    n_tasks = len(spec.tasks())
    client = cluster = None
    try:
        if len(finished_tasks(args.out, spec)) < n_tasks:  # a finished sweep is only assembled again
            client, cluster = _sweep_client(args)
        result = run_sweep(spec, args.out, client, retries=args.retries, progress=progress(args), measured=measured)
    except SweepError as exc:
        raise UsageError(str(exc)) from None
    except KeyboardInterrupt:
        print(f"simulate sweep: interrupted; finished tasks are kept in {args.out / 'tasks'} (run the same command "
              "with --resume to continue)", file=sys.stderr)
        return 130
    finally:
        if client is not None:
            client.close()
            if cluster is not None:
                cluster.close()
    _print_sweep(args, spec, result, n_tasks, resumed)
    return 1 if result.failures else 0
