"""``simulate bench`` part 2: the fiber BRDF routes, speed against accuracy (docs/quality.md C).

Case: a red-dyed fiber like the shipped red-cotton one (R = 10 um, host n = 1.557 with a
red dye absorption spectrum, Mie particles of radius 0.25 um at f_v = 0.03 with index 1.0, i.e.
voids), 33 wavelengths 390..710 nm, the in-plane (w_in, w_out) pairs of the red-cotton plan in
the warp and weft fiber frames (incidence 0/30/45/60 deg, observation -60..70 deg).

* ``nee`` (next-event, white): wall time to the target RMS relative error on ALL pairs and
  wavelengths (the headline: docs/quality.md asks <= 60 s for 1 % on 2 cores);
* all three routes side by side on one incident direction (30 deg off the axis' normal),
  one wavelength and three direction bins of the BSSRDF grid (9 x 12): wall time, standard
  error and the error against a converged next-event reference at photon budgets of 5e4,
  2e5 and 8e5 (the speed-versus-accuracy chart), and the time each would need for 1 %
  (time x (err / 0.01)^2, the N^-1/2 law, from the largest budget);
* the fabric summation's evaluations per second (:func:`summation_speed`);
* the peak resident set size.
"""

from __future__ import annotations

import math
import resource
import time
from typing import Any

import numpy as np

from simulate.fiber import Fiber, range_outputs, volume_brdf
from simulate.media.medium import MieMedium, Spectrum

__all__ = ["red_fiber", "plan_pairs", "run_fiber_bench", "chart"]


def red_fiber() -> Fiber:
    """The benchmark fiber (a stand-in for the red-cotton config, defined here so the bench is self-contained)."""
    wl = np.arange(390.0, 711.0, 10.0)
    # red dye: strong absorption below ~580 nm, weak above (1/um)
    dye = 0.002 + 0.25 / (1.0 + np.exp((wl - 585.0) / 12.0))
    medium = MieMedium(n_host=1.557, particle_n=1.0, radius_um=0.25, volume_fraction=0.03,
                       mu_a_host_per_um=Spectrum(wl, dye, "dye mu_a"), phase_table_size=2048)
    return Fiber(radius_um=10.0, n_host=1.557, medium=medium, roughness=0.3, cell_width_deg=10.0)


def plan_pairs() -> tuple[np.ndarray, np.ndarray]:
    """In-plane (w_in, w_out) pairs of the red-cotton plan in the warp and weft fiber frames."""
    w_in, w_out = [], []
    for ti in (0.0, 30.0, 45.0, 60.0):
        for s in range(-60, 71, 10):
            if abs(s + ti) < 5.0:  # beam-blocked (detector at the source)
                continue
            a, b = math.radians(ti), math.radians(s)
            wi = np.array([math.sin(a), 0.0, math.cos(a)])  # source at phi_i = 0
            # signed observation angle s: s >= 0 on the mirror side (phi_o = phi_i + 180), s < 0 source side
            wo = np.array([-math.sin(b), 0.0, math.cos(b)])
            for rot in (0.0, math.pi / 2):  # warp (fiber along x), weft (fiber along y)
                c, sn = math.cos(rot), math.sin(rot)
                m = np.array([[c, sn, 0.0], [-sn, c, 0.0], [0.0, 0.0, 1.0]])
                w_in.append(m @ wi)
                w_out.append(m @ wo)
    return np.array(w_in), np.array(w_out)


def run_fiber_bench(quick: bool = False, threads: int | None = None) -> dict[str, Any]:
    """Run the fiber benchmarks; returns a JSON-ready dictionary."""
    fiber = red_fiber()
    wl = np.arange(390.0, 711.0, 10.0) if not quick else np.array([450.0, 550.0, 650.0])
    w_in, w_out = plan_pairs()
    if quick:
        w_in, w_out = w_in[::8], w_out[::8]
    target = 0.01 if not quick else 0.05
    volume_brdf(fiber, w_in[:1], w_out[:1], wl[:1], target_rel_err=0.3, seed=0, threads=threads)  # compile/load
    t0 = time.perf_counter()
    est = volume_brdf(fiber, w_in, w_out, wl, method="nee", target_rel_err=target, seed=1, threads=threads)
    headline = {
        "pairs": int(w_in.shape[0]), "wavelengths": int(wl.size), "target_rel_err": target,
        "rel_err": est.info["rel_err"], "photons": est.photons,
        "seconds": time.perf_counter() - t0, "incident_directions": est.info["incident_directions"],
        "wavelength_groups": len(est.info["groups"]),
    }
    # routes side by side: one direction, one wavelength, bins of the BSSRDF route's own grid
    n_mu, n_phi = 9, 12
    me = np.linspace(0, 1, n_mu + 1)
    pe = np.linspace(-math.pi, math.pi, n_phi + 1)
    cells = [(8, 5), (7, 5), (6, 5)]
    out = range_outputs([me[i] for i, _ in cells], [me[i + 1] for i, _ in cells], [pe[j] for _, j in cells],
                        [pe[j + 1] for _, j in cells], fiber.half_width)
    win = np.tile([0.5, 0.0, math.sqrt(0.75)], (len(cells), 1))
    routes: dict[str, dict[str, Any]] = {}
    reference = volume_brdf(fiber, win, None, [600.0], method="nee", outputs=out, target_rel_err=0.004 if not quick
                            else 0.02, seed=99, threads=threads)
    budgets = [50_000, 200_000, 800_000] if not quick else [20_000, 60_000]
    for method in ("nee", "beam", "bssrdf"):
        runs: list[dict[str, float]] = []
        for budget in budgets:
            t = time.perf_counter()
            e = volume_brdf(fiber, win, None, [600.0], method=method, outputs=out, target_rel_err=1e-4,
                            max_photons=budget, seed=7, threads=threads, bssrdf_bins=(n_mu, n_phi))
            sec = time.perf_counter() - t
            runs.append({
                "budget": budget, "photons": e.photons, "seconds": sec,
                "rel_stderr": float(np.sqrt(np.mean((e.u_R / e.R) ** 2))),
                "rel_error_vs_reference": float(np.sqrt(np.mean(((e.R - reference.R) / reference.R) ** 2))),
            })
        last = runs[-1]
        routes[method] = {"runs": runs, "seconds_to_1pct": last["seconds"] * (last["rel_stderr"] / 0.01) ** 2}
    base = routes["nee"]["seconds_to_1pct"]
    for r in routes.values():
        r["slower_than_nee"] = r["seconds_to_1pct"] / base
    return {"headline": headline, "routes": routes, "summation": summation_speed(quick),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def summation_speed(quick: bool = False) -> dict[str, Any]:
    """(w_i, w_o, lambda) evaluations per second of the fabric summation (docs/quality.md C: >= 10^6/s).

    Random upper-hemisphere geometries, 33 wavelengths, ``R_B`` known at the unique fiber-frame
    pairs: (a) the gathers and the multiply alone (``summation_from_table``), (b) including
    building the unique pairs (``FiberPairs.from_directions``). Medians of 5 repeats.
    """
    import statistics

    from simulate.fabric import FiberPairs, summation_from_table

    rng = np.random.default_rng(0)
    g = 5_000 if quick else 50_000
    n_wl = 33

    def directions(n, max_theta_deg):
        t = np.radians(rng.uniform(0, max_theta_deg, n))
        p = rng.uniform(0, 2 * math.pi, n)
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=1)

    w_i, w_o = directions(g, 69.0), directions(g, 89.0)
    gather, full = [], []
    for _ in range(5):
        t0 = time.perf_counter()
        pairs = FiberPairs.from_directions(w_i, w_o)
        t1 = time.perf_counter()
        R_B = rng.random((pairs.n_unique, n_wl))
        t2 = time.perf_counter()
        summation_from_table(pairs, R_B, R_B)
        t3 = time.perf_counter()
        gather.append(g * n_wl / (t3 - t2))
        full.append(g * n_wl / ((t1 - t0) + (t3 - t2)))
    return {"geometries": g, "wavelengths": n_wl, "median_evals_per_s_gather": statistics.median(gather),
            "median_evals_per_s_with_pairs": statistics.median(full)}


def chart(report: dict[str, Any], path: Any) -> None:
    """Speed versus accuracy of the three routes (log-log), written to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.2), dpi=150)
    for method, marker in (("nee", "o"), ("beam", "s"), ("bssrdf", "^")):
        runs = report["routes"][method]["runs"]
        ax.loglog([r["seconds"] for r in runs], [r["rel_error_vs_reference"] for r in runs], marker=marker,
                  label=f"{method} (error vs reference)")
        ax.loglog([r["seconds"] for r in runs], [r["rel_stderr"] for r in runs], marker=marker, linestyle=":",
                  alpha=0.6, label=f"{method} (reported std. error)")
    ax.axhline(0.01, color="grey", lw=0.8)
    ax.set_xlabel("wall time (s)")
    ax.set_ylabel("RMS relative error")
    ax.set_title("Fiber volume BRDF: speed versus accuracy")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
