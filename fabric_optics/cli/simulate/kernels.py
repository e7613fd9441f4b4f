"""``simulate compile``: the compiled kernels a fabric run needs, compiled into the kernel cache ahead of it.

The work is :func:`simulate.precompile.compile_kernels`: a tiny run of the config's model, whose
compilations stay in the kernel cache (:mod:`simulate.kernelcache`); it writes nothing else.
"""

from __future__ import annotations

import argparse

from fabric_optics import api
from fabric_optics.cli.common import UsageError, add_plan

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``simulate compile``."""
    from simulate.precompile import COMPILE_METHODS

    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name, e.g. green-felt-mc)")
    p.add_argument("--method", choices=COMPILE_METHODS, required=True,
                   help="the fabric model whose kernels are compiled, as `simulate fabric --method` takes it "
                        "(auto: every model's)")
    add_plan(p, what="whose wavelengths the run will simulate")


def run(args: argparse.Namespace) -> int:
    """Run ``simulate compile``; return the exit status."""
    from simulate.config import ConfigError
    from simulate.precompile import compile_kernels
    from simulate.products import check_blend

    config = api.load_config(args.config)
    try:
        plan = api.load_plan(args.plan)
    except api.InputError as exc:
        raise UsageError(f"--plan: {exc}") from None
    try:
        check_blend(config, args.method)
    except ConfigError as exc:
        raise UsageError(str(exc)) from None
    done = compile_kernels(config, args.method, plan.wavelengths_nm)
    what = f"{config.name} --method {args.method}"
    if done.kernels:
        print(f"compiled {len(done.kernels)} kernels of {what} into {done.cache} ({done.seconds:.1f} s)")
    else:
        print(f"compiled 0 kernels: those of {what} are in {done.cache} already ({done.seconds:.1f} s)")
    return 0
