"""The felt study: the felt Monte Carlo against the felt's structured summation, absorbing and not.

``simulate bench --study felt --out DIR [--quick]`` builds the felt of :mod:`simulate.geometry.felt`
(HG fiber: R 10 um, n 1.5, mu_s 0.8 /um, g 0.5, RMS slope 0.35; ``[structure] kind = "nonwoven"``,
touching layers; seed 0) and reports, in ``DIR/felt.json`` and on stdout:

1. the felt: its fibers, thickness, bulk volume fraction, and -- counted on the mesh -- the fraction
   of the fibers' surface that lies inside another fiber (0: the fibers are deposited without
   overlaps; a buried surface would start a walk of the other fiber's full volume);
2. per fiber absorption ``mu_a`` (0.01, 0.0068, 0.005, 0 /um): the felt Monte Carlo and the structured
   summation at incidence 0 / observation 10 deg, and their ratio with its standard error -- where the
   summation's layers of touching fibers and the deposited felt part, and how that grows as the fibers
   clear (docs/physics.md 6, "the felt").

:func:`run_felt_study` takes the packing fraction and layers too: ``packing_fraction=0.11, layers=29``
compares the two at the deposited felt's own volume fraction with the fiber amount of 10 touching layers.
``--quick``: two absorptions at a loose target (a smoke test of a few minutes on two cores).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from simulate import fabric as fab
from simulate import fiber as F
from simulate import raytrace as W
from simulate.fabric import structure as ST
from simulate.geometry.felt import felt_mesh, fiber_pieces
from simulate.media.medium import HGMedium
from simulate.products import all_threads

R_UM = 10.0


def buried_fraction(m: Any, n: int = 20_000, seed: int = 1) -> float:
    """The fraction of the fibers' surface (in the cell) that lies inside another fiber image.

    ``m`` is a :class:`simulate.geometry.mesh.FabricMesh`; the fraction is estimated from random points
    on random fiber images.
    """
    if m.info.get("crimp_amplitude_um", 0.0) > 0.0:
        return _buried_fraction_pieces(m, n, seed)
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


def _buried_fraction_pieces(m: Any, n: int, seed: int) -> float:
    """:func:`buried_fraction` of a felt of crimped fibers.

    Random points on the pieces of the fibers' polylines (:func:`simulate.geometry.felt.fiber_pieces`), inside
    another image's piece cylinder.
    """
    S, D = fiber_pieces(m)
    R = float(m.yarn_radius_um)
    length = np.linalg.norm(D, axis=2)
    rng = np.random.default_rng(seed)
    k = rng.integers(0, S.shape[0], n)
    i = rng.integers(0, S.shape[1], n)
    f = rng.uniform(0.0, 1.0, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    t = D[k, i] / length[k, i][:, None]
    helper = np.where(np.abs(t[:, 2:3]) < 0.9, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
    u = np.cross(helper, t)
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(t, u)
    p = S[k, i] + f[:, None] * D[k, i] + R * (np.cos(ph)[:, None] * u + np.sin(ph)[:, None] * v)
    keep = (p[:, 0] >= 0) & (p[:, 0] < m.Lx) & (p[:, 1] >= 0) & (p[:, 1] < m.Ly)
    p, k = p[keep], k[keep]
    buried = np.zeros(len(p), bool)
    for j in range(S.shape[0]):
        e = D[j] / length[j][:, None]
        d = p[None, :, :] - (S[j] + 0.5 * D[j])[:, None, :]
        a = np.einsum("pij,pj->pi", d, e)
        r2 = np.einsum("pij,pij->pi", d, d) - a * a
        buried |= (j != k) & ((np.abs(a) <= 0.5 * length[j][:, None]) & (r2 < R * R)).any(axis=0)
    return float(buried.mean())


#: the full study's absorptions (1/um) and target; ``quick``'s
MU_A = (0.01, 0.0068, 0.005, 0.0)
QUICK_MU_A = (0.01, 0.0)


def run_felt_study(*, quick: bool = False, mu_a: tuple[float, ...] | None = None,
                   packing_fraction: float = ST.CLOSE_PACKING, layers: int = 0, target_rel_err: float | None = None,
                   seed: int = 0, threads: int | None = 1) -> dict[str, Any]:
    """The study's figures (module docstring) as a JSON-ready dict: ``felt`` and one row per ``mu_a``."""
    mu_a = tuple(mu_a if mu_a is not None else (QUICK_MU_A if quick else MU_A))
    target = float(target_rel_err if target_rel_err is not None else (0.1 if quick else 0.015))
    summation_target = max(target, 0.02)
    spec = ST.StructureSpec(kind="nonwoven", packing_fraction=packing_fraction, layers=layers)
    mesh = felt_mesh(spec, R_UM, seed=seed)
    felt = {"packing_fraction": packing_fraction, "seed": seed, "fibers": int(mesh.info["fibers"]),
            "thickness_um": float(mesh.info["thickness_um"]), "volume_fraction": float(mesh.info["volume_fraction"]),
            "buried_surface_fraction": buried_fraction(mesh)}
    w_i, w_o = fab.directions_deg([0.0], [0.0]), fab.directions_deg([10.0], [180.0])
    rows = []
    for a in mu_a:
        fib = F.Fiber(R_UM, 1.5, HGMedium(mu_s=0.8, mu_a=float(a), g=0.5), 0.35, 10.0)
        bs, us, _ = ST.structured_beta(spec, fib, None, w_i, w_o, [550.0], target_rel_err=summation_target, seed=1,
                                       threads=threads)
        b, u, _ = W.fabric_beta(mesh, fib, w_i, w_o, np.array([550.0]), target_rel_err=target, seed=seed,
                                threads=all_threads(threads))
        ratio = float(b[0, 0] / bs[0, 0])
        rows.append({"mu_a_per_um": float(a), "mc": float(b[0, 0]), "u_mc": float(u[0, 0]),
                     "summation": float(bs[0, 0]), "u_summation": float(us[0, 0]), "ratio": ratio,
                     "u_ratio": ratio * math.hypot(float(u[0, 0] / b[0, 0]), float(us[0, 0] / bs[0, 0]))})
    return {"study": "felt", "quick": quick, "target_rel_err": target, "felt": felt, "rows": rows}


def felt_study_lines(report: dict[str, Any]) -> list[str]:
    """The study as text, one line for the felt and one per absorption."""
    f = report["felt"]
    lines = [f"felt, packing {f['packing_fraction']:.4f}, seed {f['seed']}: {f['fibers']} fibers, "
             f"{f['thickness_um']:.0f} um thick, bulk volume fraction {f['volume_fraction']:.3f}; fiber surface inside "
             f"another fiber {f['buried_surface_fraction']:.4f}"]
    for r in report["rows"]:
        lines.append(f"mu_a {r['mu_a_per_um']:<7g} felt MC {r['mc']:.4f} +- {r['u_mc']:.4f}   summation "
                     f"{r['summation']:.4f} +- {r['u_summation']:.4f}   ratio {r['ratio']:.3f} +- {r['u_ratio']:.3f}")
    return lines
