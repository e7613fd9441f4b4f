"""The felt Monte Carlo against the felt summation, absorbing and not (issue 19, docs/physics.md 6).

``python -m fabric_optics.bench.woven_felt [--mu-a 0.01,0.0068,0.005,0] [--packing 0.9069] [--layers 0]
[--seed 0] [--target 0.015]`` prints, for the felt of :mod:`simulate.woven.felt` (HG fiber: R 10 um,
n 1.5, mu_s 0.8 /um, g 0.5, RMS slope 0.35; ``[structure] kind = "nonwoven"`` with that packing
fraction and layers; the felt and its rays from ``--seed``):

1. the felt: its fibers, thickness, bulk volume fraction, and -- counted on the mesh -- the fraction
   of the fibers' surface that lies inside another fiber (where the tracer's interpenetration rule
   would start a new walk of that fiber's full volume: 0.48 before the fibers were deposited without
   overlaps, 0 now);
2. per absorption ``mu_a``: the felt Monte Carlo and the structured summation at incidence 0 /
   observation 10 deg, and their ratio with its standard error. ``--packing 0.11 --layers 29``
   compares them at the deposited felt's own volume fraction with the fiber amount of 10 touching
   layers.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

import numpy as np

from simulate import fabric as fab
from simulate import fiber as F
from simulate import woven as W
from simulate.fabric import structure as ST
from simulate.media.medium import HGMedium
from simulate.woven.felt import felt_mesh

R_UM = 10.0


def buried_fraction(m: Any, n: int = 20_000, seed: int = 1) -> float:
    """The fraction of the fibers' surface (in the cell) that lies inside another fiber image
    (``m`` a :class:`simulate.woven.felt.FeltMesh`; random points on random fiber images)."""
    ring = (int(m.n_s[0]) + 1) * (int(m.sides) + 1)
    cent = np.array([m.vertices[b:b + ring].reshape(int(m.n_s[0]) + 1, int(m.sides) + 1, 3)[:, :-1].mean(axis=(0, 1)) for b in m.vertex_base])
    tan = m.tangents[m.vertex_base]
    ell = float(m.info["fiber_length_um"])
    rng = np.random.default_rng(seed)
    k = rng.integers(0, len(cent), n)
    s = rng.uniform(-ell / 2, ell / 2, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    t = tan[k]
    helper = np.where(np.abs(t[:, 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    u = np.cross(helper, t)
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(t, u)
    p = cent[k] + s[:, None] * t + R_UM * (np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v)
    keep = (p[:, 0] >= 0) & (p[:, 0] < m.Lx) & (p[:, 1] >= 0) & (p[:, 1] < m.Ly)
    p, k = p[keep], k[keep]
    buried = np.zeros(len(p), bool)
    for j in range(len(cent)):
        d = p - cent[j]
        a = d @ tan[j]
        r2 = np.einsum("ij,ij->i", d, d) - a * a
        buried |= (j != k) & (np.abs(a) <= ell / 2) & (r2 < R_UM * R_UM)
    return float(buried.mean())


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--mu-a", default="0.01,0.0068,0.005,0")
    ap.add_argument("--packing", type=float, default=ST.CLOSE_PACKING)
    ap.add_argument("--layers", type=int, default=0, help="[structure] layers (0: the felt's default, 10)")
    ap.add_argument("--target", type=float, default=0.015)
    ap.add_argument("--seed", type=int, default=0, help="the felt's and the Monte Carlo's seed")
    a = ap.parse_args(argv)
    spec = ST.StructureSpec(kind="nonwoven", packing_fraction=a.packing, layers=a.layers)
    mesh = felt_mesh(spec, R_UM, seed=a.seed)
    print(f"felt, packing {a.packing:.4f}, seed {a.seed}: {mesh.info['fibers']} fibers, {mesh.info['thickness_um']:.0f} um "
          f"thick, bulk volume fraction {mesh.info['volume_fraction']:.3f}; fiber surface inside another fiber "
          f"{buried_fraction(mesh):.4f}", flush=True)
    w_i, w_o = fab.directions_deg([0.0], [0.0]), fab.directions_deg([10.0], [180.0])
    for mu_a in (float(x) for x in a.mu_a.split(",")):
        fib = F.Fiber(R_UM, 1.5, HGMedium(mu_s=0.8, mu_a=mu_a, g=0.5), 0.35, 10.0)
        bs, us, _ = ST.structured_beta(spec, fib, None, w_i, w_o, [550.0], target_rel_err=0.02, seed=1, threads=1)
        b, u, _ = W.fabric_beta(mesh, fib, w_i, w_o, np.array([550.0]), target_rel_err=a.target, seed=a.seed, threads=1)
        print(f"mu_a {mu_a:<7g} felt MC {b[0, 0]:.4f} +- {u[0, 0]:.4f}   summation {bs[0, 0]:.4f} +- {us[0, 0]:.4f}"
              f"   ratio {b[0, 0] / bs[0, 0]:.3f} +- {b[0, 0] / bs[0, 0] * math.hypot(u[0, 0] / b[0, 0], us[0, 0] / bs[0, 0]):.3f}",
              flush=True)


if __name__ == "__main__":
    main()
