"""The re-weighted felt Monte Carlo against re-traced runs over the dyes a fit explores (docs/notes/reweighted-mc.md).

    gonio demo --sample fixtures/real/acrylic_felt_green_rgb.bsdf --plan measured --out DIR/measured
    python docs/scripts/reweighted_mc.py DIR/measured --json DIR/reweighted-mc.json

The ``make demo`` Monte Carlo fit's run: green-felt-mc at the measured plan's geometries, 3 % target, seed 0, its
eight dye knots (``--free dye``). The start's dye is traced once with a record (:mod:`simulate.raytrace.reweight`);
the record is re-weighted to the start's own dye (equal to rounding) and to each dye of :data:`DYES`, and each of
those is traced again at the same seed (the same tables: a trace of that dye walks them). Per dye: the z-scores
``(rw - traced) / sqrt(u_rw^2 + u_traced^2)`` over every geometry and wavelength, and ``z_rays`` with the rays' parts
of the errors only (the table's part is shared by the two runs and cancels in their difference), both runs' relative
errors, the
spread (re-weighted ray error over the traced start's at the same rays), the level ratio ``sum rw / sum traced``,
whether the fit would keep the re-weighting (:func:`fabric_optics.fitting.spacemapping.reweight_accepted`), and
each one's wall and CPU seconds. The record's size and event counts are reported with the first trace.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

#: the dyes: the start's absorption scaled (every knot's log10 moved by log10 of the factor), and a hue change (the
#: knots' values moved one knot along the wavelengths) -- the range a dye fit's proposals span from its start
DYES = (("x0.5", 0.5), ("x0.8", 0.8), ("x1.25", 1.25), ("x2", 2.0), ("hue", None))


def _run(problem, x, geoms, record=None):
    """Trace the felt Monte Carlo at ``x`` (filling ``record`` when given): the estimate, its wall and CPU seconds."""
    from simulate.products import RunSettings, all_threads, evaluate

    cfg = problem.config_at(x)
    wl = problem.wavelengths_nm
    t, c = time.perf_counter(), time.process_time()
    est = evaluate("mc", cfg, cfg.fiber(wl), geoms, wl,
                   RunSettings(target=problem.target_rel_err, seed=0, threads=all_threads(None), record=record))
    return est, time.perf_counter() - t, time.process_time() - c


def main(argv: list[str] | None = None) -> int:
    """Trace the start's dye with a record, re-weight it to each dye of :data:`DYES` and compare with re-traced runs.

    The JSON is rewritten after each dye, so a run stopped midway keeps the dyes already compared.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (the measurement, ``--json``, ``--target-rel-err``); ``sys.argv[1:]``
        when None.

    Returns
    -------
    int
        0 (argparse exits 2 on a bad argument).
    """
    from fabric_optics import api
    from fabric_optics.fitting.spacemapping import reweight_accepted
    from simulate.montecarlo.accuracy import relative_error
    from simulate.products import Geometries, reweighted_estimate
    from simulate.provenance import machine
    from simulate.raytrace import reweight as RW

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("measured", help="the demo's acquisition (gonio demo --plan measured)")
    ap.add_argument("--json", required=True, help="output file")
    ap.add_argument("--target-rel-err", type=float, default=0.03)
    args = ap.parse_args(argv)
    job = api.prepare_fit("green-felt-mc", args.measured, "dye", Path(args.json).with_suffix(".fit-unused"),
                          method="mc", target_rel_err=args.target_rel_err, force=True)
    problem = job.problem
    wl = problem.wavelengths_nm
    g = problem.geometries
    geoms = Geometries(*(g[c].to_numpy(float) for c in ("theta_i", "phi_i", "theta_o", "phi_o")))
    x0 = problem.start.copy()
    record: dict = {}
    est0, wall0, cpu0 = _run(problem, x0, geoms, record)
    chunks = [c for inc in record["incidences"] for t in inc["realisations"] for c in t.chunks]
    traced_rel = float(relative_error(est0.beta, est0.u_beta))
    t, c = time.perf_counter(), time.process_time()
    b, u, _ = reweighted_estimate(record, problem.config_at(x0), wl)
    same = {"max_rel_diff_beta": float(np.max(np.abs(b - est0.beta) / np.maximum(np.abs(est0.beta), 1e-300))),
            "max_rel_diff_u_beta": float(np.max(np.abs(u - est0.u_beta) / np.maximum(est0.u_beta, 1e-300))),
            "wall_s": time.perf_counter() - t, "cpu_s": time.process_time() - c}
    data: dict = {"traced": {"wall_s": wall0, "cpu_s": cpu0, "rays": int(est0.info["rays"]), "rel_err": traced_rel,
                             "event_bytes": RW.record_bytes(record),
                             "hits": int(sum(c.hit_ray.size for c in chunks)),
                             "scores": int(sum(c.nee_hit.size for c in chunks)),
                             "geometries": int(est0.beta.shape[0]), "wavelengths": int(wl.size)},
                  "same_dye": same, "dyes": []}
    out = {"name": "reweighted-mc",
           "command": f"python docs/scripts/reweighted_mc.py DIR/measured --json DIR/reweighted-mc.json"
                      f"{'' if args.target_rel_err == 0.03 else f' --target-rel-err {args.target_rel_err:g}'}",
           "machine": machine(), "data": data}
    for name, factor in DYES:
        x = np.roll(x0, 1) if factor is None else x0 + np.log10(factor)
        x = np.clip(x, problem.low, problem.high)
        t, c = time.perf_counter(), time.process_time()
        b, u, info = reweighted_estimate(record, problem.config_at(x), wl)
        rw_wall, rw_cpu = time.perf_counter() - t, time.process_time() - c
        again: dict = {}
        est, wall, cpu = _run(problem, x, geoms, again)
        # the re-traced run's rays' part of its error (its own record replayed at its own dye: its result)
        _, _, info_again = reweighted_estimate(again, problem.config_at(x), wl)
        del again
        z_all = (b - est.beta) / np.sqrt(u ** 2 + est.u_beta ** 2)
        z = z_all[np.isfinite(z_all)]
        # both runs walk the same tables, so the table's part of u_beta is shared and cancels in the difference:
        # z_rays leaves it out (the rays' parts only)
        zr = (b - est.beta) / np.sqrt(info["u_rays"] ** 2 + info_again["u_rays"] ** 2)
        zr = zr[np.isfinite(zr)]
        data["dyes"].append({
            "dye": name, "x": x.tolist(), "n": int(z.size), "z_mean": float(np.mean(z)),
            "z_rms": float(np.sqrt(np.mean(z ** 2))), "z_max_abs": float(np.max(np.abs(z))),
            "frac_abs_z_gt_2": float(np.mean(np.abs(z) > 2.0)), "frac_abs_z_gt_3": float(np.mean(np.abs(z) > 3.0)),
            "z_rays_mean": float(np.mean(zr)), "z_rays_rms": float(np.sqrt(np.mean(zr ** 2))),
            "z_rays_max_abs": float(np.max(np.abs(zr))), "frac_abs_z_rays_gt_3": float(np.mean(np.abs(zr) > 3.0)),
            "level_ratio": float(np.sum(b) / np.sum(est.beta)),
            "rel_err_reweighted": float(info["rel_err"]), "rel_err_retraced": float(relative_error(est.beta, est.u_beta)),
            "ray_rel_err_reweighted": float(info["ray_rel_err"]), "spread": float(info["spread"]),
            "accepted": bool(reweight_accepted(info, problem.target_rel_err, traced_rel)),
            "reweight_wall_s": rw_wall, "reweight_cpu_s": rw_cpu, "trace_wall_s": wall, "trace_cpu_s": cpu})
        print(json.dumps(data["dyes"][-1]), flush=True)
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
