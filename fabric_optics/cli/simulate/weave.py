"""``simulate weave``: the yarn tubes of a config's woven micro-element as a PLY or OBJ mesh.

The geometry is :mod:`simulate.geometry.weave`, the mesh :func:`simulate.geometry.mesh.mesh`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fabric_optics import api
from fabric_optics.cli.common import (
    UsageError,
    add_force,
    refuse_existing,
)

__all__ = ["add_arguments", "run"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The arguments of ``simulate weave``."""
    p.add_argument("config", metavar="CONFIG", help="simulation config (TOML path or preset name); its [weave] "
                                                     "table (default: a plain weave)")
    p.add_argument("--out", type=Path, required=True, help="mesh file to write, .ply or .obj")
    add_force(p, "an existing --out file")


def run(args: argparse.Namespace) -> int:
    """Run ``simulate weave``; return the exit status."""
    from simulate.config import ConfigError, weave_from_config
    from simulate.geometry.mesh import mesh
    from simulate.geometry.weave import WeaveError

    out: Path = args.out
    if out.suffix.lower() not in (".ply", ".obj"):
        raise UsageError(f"--out {out}: unknown mesh format {out.suffix or '(no suffix)'!r}; use .ply or .obj")
    if out.is_dir():
        raise UsageError(f"--out {out}: is a directory; give a mesh file name (.ply or .obj)")
    refuse_existing(out, args.force)
    config = api.load_config(args.config)
    try:
        weave = weave_from_config(config)
        m = mesh(weave)
        m.export(out)
    except (ConfigError, WeaveError) as exc:
        raise UsageError(str(exc)) from None
    print(f"wrote {out} ({len(m.vertices)} vertices, {len(m.faces)} faces; {weave.n_warp} warp x "
          f"{weave.n_weft} weft yarns, micro-element {m.Lx:g} x {m.Ly:g} um, z {m.z_min:g}..{m.z_max:g} um)")
    return 0
