"""Why the felt Monte Carlo is darker than the felt summation for an absorbing fiber (issue 19, docs/physics.md 6).

``python -m studies.bench_woven_felt [--mu-a 0.01,0.0068,0.005,0] [--packing 0.9069] [--target 0.015]``
prints, for the felt of :mod:`simulate.woven.felt` (HG fiber: R 10 um, n 1.5, mu_s 0.8 /um, g 0.5,
RMS slope 0.35; ``[structure] kind = "nonwoven"`` with that packing fraction):

1. its interpenetration: the fibers' summed volume fraction in the slab, the fraction of the slab
   covered by at least one fiber if the centres were a Poisson process (``1 - exp(-f)``), the mean
   number of fibers covering a covered point (their ratio), and -- counted on the mesh -- the
   fraction of the fibers' surface that lies inside another fiber (where the tracer's
   interpenetration rule starts a new walk of that fiber's full volume);
2. per absorption ``mu_a``: the felt Monte Carlo and the structured summation at incidence 0 /
   observation 10 deg, and their ratio.
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
    cent = np.array([m.vertices[b:b + ring].mean(axis=0) for b in m.vertex_base])
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
    ap.add_argument("--target", type=float, default=0.015)
    a = ap.parse_args(argv)
    spec = ST.StructureSpec(kind="nonwoven", packing_fraction=a.packing)
    mesh = felt_mesh(spec, R_UM, seed=0)
    f = float(mesh.info["volume_fraction"])
    cover = 1.0 - math.exp(-f)
    print(f"felt, packing {a.packing:.4f}: {mesh.info['fibers']} fibers, summed volume fraction {f:.3f}, "
          f"Poisson covered {cover:.3f}, multiplicity {f / cover:.2f}; fiber surface inside another fiber "
          f"{buried_fraction(mesh):.3f}")
    w_i, w_o = fab.directions_deg([0.0], [0.0]), fab.directions_deg([10.0], [180.0])
    for mu_a in (float(x) for x in a.mu_a.split(",")):
        fib = F.Fiber(R_UM, 1.5, HGMedium(mu_s=0.8, mu_a=mu_a, g=0.5), 0.35, 10.0)
        bs, us, _ = ST.structured_beta(spec, fib, None, w_i, w_o, [550.0], target_rel_err=0.02, seed=1, threads=1)
        b, u, _ = W.fabric_beta(mesh, fib, w_i, w_o, np.array([550.0]), target_rel_err=a.target, seed=0, threads=1)
        print(f"mu_a {mu_a:<7g} felt MC {b[0, 0]:.4f} +- {u[0, 0]:.4f}   summation {bs[0, 0]:.4f} +- {us[0, 0]:.4f}"
              f"   ratio {b[0, 0] / bs[0, 0]:.3f}")


if __name__ == "__main__":
    main()
