"""Tube resolution of the woven Monte Carlo: the geometry error of a coarse mesh against a fine one (issue 19).

``python -m fabric_optics.bench.tube [--rays N] [--sides 8,16,...] [--points 4,8,...] [--ref-sides S] [--ref-points P]``
traces the red-cotton weave (plain, spacing 300, width 250, height 100 um) with Lambertian yarns
(albedo 0.6: a fast material whose transport is all geometry) at incidences 0, 30, 60 deg towards
detectors at 0-70 deg in three azimuths, for each (sides, points per span), with the same seeds, and
prints the relative difference of ``beta`` from the fine reference tube: the mean and the worst
over the detectors, the reference's own standard error, and the seconds per run. The fine tube is
the reference because the mesh converges to the smooth tube of :mod:`simulate.fabric.weave`.
"""

from __future__ import annotations

import argparse

import numpy as np

from simulate import woven as W
from simulate.fabric import weave
from simulate.fabric.mesh import mesh as weave_mesh

INCIDENCES_DEG = (0.0, 30.0, 60.0)


def _dirs(theta_deg, phi_deg) -> np.ndarray:
    t, p = np.meshgrid(np.radians(theta_deg), np.radians(phi_deg), indexing="ij")
    t, p = t.ravel(), p.ravel()
    return np.column_stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


DETECTORS = _dirs([0.0, 10.0, 25.0, 40.0, 55.0, 70.0], [0.0, 45.0, 180.0])


def run(sides: int, points: int, rays: int, seed: int = 0, rho: float = 0.6) -> tuple[np.ndarray, np.ndarray, float]:
    """``beta, u_beta [incidence, detector]`` and the seconds of one tube resolution."""
    wv = weave.Weave(np.array([[1, 0], [0, 1]]), spacing_um=300.0, width_um=250.0, height_um=100.0,
                     points_per_span=points, sides=sides)
    mesh = weave_mesh(wv)
    b, u, sec = [], [], 0.0
    for k, th in enumerate(INCIDENCES_DEG):
        w_in = _dirs([th], [20.0])[0]
        r = W.trace(mesh, W.Lambert(rho), w_in, DETECTORS, target_rel_err=1e-9, max_rays=rays, seed=seed + k,
                    chunk=8192)
        b.append(r.beta[:, 0])
        u.append(r.u_beta[:, 0])
        sec += r.seconds
    return np.array(b), np.array(u), sec


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=262_144)
    ap.add_argument("--sides", default="8,12,16,24,32,48,64")
    ap.add_argument("--points", default="8")
    ap.add_argument("--ref-sides", type=int, default=128)
    ap.add_argument("--ref-points", type=int, default=32)
    a = ap.parse_args(argv)
    ref, u_ref, sec = run(a.ref_sides, a.ref_points, a.rays)
    print(f"reference: {a.ref_sides} sides, {a.ref_points} points per span, {a.rays} rays per incidence, "
          f"{sec:.1f} s; its RMS relative standard error {np.sqrt(np.mean((u_ref / ref) ** 2)):.3%}")
    print("sides  points  mean rel. diff  mean |rel. diff|  worst |rel. diff|  RMS rel. SE of diff  seconds")
    for p in (int(x) for x in a.points.split(",")):
        for s in (int(x) for x in a.sides.split(",")):
            b, u, sec = run(s, p, a.rays)
            d = b / ref - 1.0
            se = np.sqrt(np.mean((np.hypot(u, u_ref) / ref) ** 2))
            print(f"{s:5d}  {p:6d}  {d.mean():+14.3%}  {np.abs(d).mean():16.3%}  {np.abs(d).max():17.3%}  "
                  f"{se:19.3%}  {sec:7.1f}")


if __name__ == "__main__":
    main()
