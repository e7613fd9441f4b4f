"""A ring or core dye's absorption table and the fit that frees its depth (docs/notes/felt-structure.md, section 11).

    python docs/scripts/dye_depth_check.py --json DIR/dye-depth.json

Three measurements at fixed seeds:

* ``shell``: the absorption table (:mod:`simulate.fiber.absorption`) of a clear unit fiber (n 1.5) whose dye sits
  in a ring 0.2 deep or a core below a 0.4 skin, perpendicular incidence, read at its nodes, against the closed form
  of straight chords through the annulus (every chord of a ray inside a circle keeps its distance from the axis;
  Fresnel at every crossing, internal reflections summed): the exited fraction, its standard error, the difference
  in standard errors.
* ``mc``: the table of the green felt's fiber with a ring dye 1.5 um deep (walked white, read at three times the
  preset's dye at 450/550/650 nm) against the fiber Monte Carlo of the dyed fiber (its own seed), and the uniform
  dye's: two exit ranges of an oblique beam.
* ``fits``: red cotton with its dye in a ring, a synthetic measurement made by the model at a known depth (mock
  noise, 6 wavelengths, incidences 0 and 30 deg), fitted from another depth: the classic model and the structured
  summation; and the green felt with its dye in a ring, measured by the felt Monte Carlo at a known depth (1 %
  noise), fitted back by the Monte Carlo's fit (output space mapping; every run traced at its depth).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import time
import tomllib
from pathlib import Path

import numpy as np


def _fresnel(cos_i: np.ndarray, n1: float, n2: float) -> np.ndarray:
    """Unpolarised Fresnel reflectance from index ``n1`` into ``n2`` at the cosines ``cos_i`` (1 beyond the critical angle)."""
    c = np.clip(np.abs(cos_i), 0.0, 1.0)
    sin2_t = (n1 / n2) ** 2 * (1.0 - c * c)
    ct = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    rs = ((n1 * c - n2 * ct) / (n1 * c + n2 * ct)) ** 2
    rp = ((n2 * c - n1 * ct) / (n2 * c + n1 * ct)) ** 2
    return np.where(sin2_t >= 1.0, 1.0, 0.5 * (rs + rp))


def annulus(n: float, mu: float, a: float, kind: str, m: int = 400_000) -> float:
    """The exited fraction of a clear unit cylinder dyed (``mu``) beyond (ring) or within (core) the radius ``a``.

    Straight chords at perpendicular incidence, summed over ``m`` impact parameters: every chord of a
    ray inside a circle keeps its distance from the axis, so each internal pass crosses the same dyed
    length; Fresnel at every crossing, the internal reflections summed as a geometric series.

    Parameters
    ----------
    n : float
        The fiber's refractive index (in air).
    mu : float
        The dye's absorption coefficient, per unit radius.
    a : float
        The radius between the dyed and the clear part.
    kind : {"ring", "core"}
        ``ring``: dyed beyond ``a`` (a skin of depth ``1 - a``); ``core``: dyed within ``a``.
    m : int
        Number of impact parameters (midpoints of equal steps across the diameter).

    Returns
    -------
    float
        The fraction of the incident light that leaves the fiber, after any number of internal passes.
    """
    b = (np.arange(m) + 0.5) / m * 2.0 - 1.0
    f = _fresnel(np.sqrt(1.0 - b * b), 1.0, n)
    d = np.abs(b) / n
    chord = 2.0 * np.sqrt(1.0 - d * d)
    inner = 2.0 * np.sqrt(np.clip(a * a - d * d, 0.0, None))
    A = np.exp(-mu * (chord - inner if kind == "ring" else inner))
    return float(np.mean((1.0 - f) ** 2 * A / (1.0 - f * A)))


def shell(target: float) -> list[dict]:
    """A clear fiber's absorption table with a ring or core dye against the closed form of :func:`annulus`.

    Parameters
    ----------
    target : float
        The table's target relative error (``target_rel_err`` of its walk).

    Returns
    -------
    list of dict
        One row per profile (ring 0.2 deep, core below a 0.4 skin) and table node: the node's
        absorption per radius, the table's exited fraction and its standard error, the closed form, their
        difference in standard errors (``z``), the uniform dye's closed form, the table's seconds and photons.
    """
    from simulate.fiber import Fiber, range_outputs
    from simulate.fiber.absorption import absorption_nodes, absorption_table
    from simulate.media.medium import HGMedium

    rows = []
    for kind, depth in (("ring", 0.2), ("core", 0.4)):
        fib = Fiber(radius_um=1.0, n_host=1.5, medium=HGMedium(mu_s=1e-9, mu_a=0.0, g=0.0), roughness=0.3,
                    cell_width_deg=30.0, dye_profile=kind, dye_depth_um=depth)
        hw = fib.half_width
        outputs = np.vstack([range_outputs([0.0], [1.0], [-math.pi], [math.pi], hw, psi)
                             for psi in np.arange(12) * 2.0 * math.pi / 12])
        t = time.perf_counter()
        table = absorption_table(fib, np.repeat([[0.0, 0.0, 1.0]], 12, axis=0), outputs, [550.0],
                                 absorption_nodes(4.0), method="beam", target_rel_err=target, seed=3)
        seconds = time.perf_counter() - t
        for node in (11, 14):
            mu = float(table.nodes[node])
            R, u = table(np.array([mu]))
            exited = float(R[:, 0].sum() * math.pi * hw)
            u_exited = float(np.sqrt(np.sum(u[:, 0] ** 2)) * math.pi * hw)
            expected = annulus(1.5, mu, 1.0 - depth, kind)
            rows.append({"profile": kind, "depth": depth, "mu_per_radius": mu, "table": exited, "u_table": u_exited,
                         "closed_form": expected, "z": (exited - expected) / u_exited,
                         "uniform_closed_form": annulus(1.5, mu, 0.0, "ring"), "seconds": seconds,
                         "photons": int(sum(table.photons.values()))})
    return rows


def against_mc(target: float) -> dict:
    """The green felt's absorption table with a ring dye against the fiber Monte Carlo of the dyed fiber.

    Parameters
    ----------
    target : float
        Target relative error of the table's walk and of the two Monte Carlo runs.

    Returns
    -------
    dict
        The wavelengths, the dye (three times the preset's), the two exit ranges, the table's and the
        traced reflectances with their standard errors, their difference in standard errors (``z``) and
        the uniform dye's traced reflectance.
    """
    from simulate.config import load_config
    from simulate.config_dye import DyeSpectrum
    from simulate.fiber import range_outputs, volume_brdf
    from simulate.fiber.absorption import absorption_nodes, absorption_table

    wl = np.array([450.0, 550.0, 650.0])
    cfg = load_config("green-felt-mc")
    mu = cfg.dye(wl) * 3.0
    dye = DyeSpectrum("table", {"wavelength_nm": [400.0, *wl, 700.0], "mu_a_per_um": [mu[0], *mu, mu[-1]]})
    cfg = dataclasses.replace(cfg, dye=dye, dye_profile="ring", dye_depth_um=1.5, transmission_rms_slope=0.0,
                              transmission_rms_slope_around=None)
    w_in = np.repeat([[0.0, 0.6, 0.8]], 2, axis=0)
    undyed = cfg.undyed().fiber(wl)
    outputs = range_outputs([0.0, 0.5], [0.5, 1.0], [-math.pi, -math.pi], [math.pi, math.pi], undyed.half_width)
    table = absorption_table(undyed, w_in, outputs, wl, absorption_nodes(2.0), method="beam", target_rel_err=target,
                             seed=5)
    R, u = table(cfg.dye(wl))
    traced = volume_brdf(cfg.fiber(wl), w_in, None, wl, method="beam", outputs=outputs, target_rel_err=target, seed=6)
    uniform = volume_brdf(dataclasses.replace(cfg, dye_profile="uniform").fiber(wl), w_in, None, wl, method="beam",
                          outputs=outputs, target_rel_err=target, seed=6)
    return {"wavelength_nm": wl.tolist(), "dye_per_um": mu.tolist(), "exit_mu_ranges": [[0.0, 0.5], [0.5, 1.0]],
            "table": R.tolist(), "u_table": u.tolist(), "traced": traced.R.tolist(), "u_traced": traced.u_R.tolist(),
            "z": ((R - traced.R) / np.hypot(u, traced.u_R)).tolist(), "uniform": uniform.R.tolist()}


def fits(methods: tuple[str, ...]) -> list[dict]:
    """Fit a ring dye's depth from a synthetic measurement of red cotton made by the model at a known depth.

    Parameters
    ----------
    methods : tuple of str
        The fits to run, of ``classic``, ``summation`` and ``mc`` (others are ignored; ``mc`` is the felt's, see
        :func:`mc_fit`).

    Returns
    -------
    list of dict
        One per method run: its target error, the true, starting and fitted depths (um), the fit's
        standard uncertainty and the error in those, the objective at the start and the end, the walks
        and the seconds.
    """
    from fabric_optics.fitting.problem import FitProblem
    from fabric_optics.fitting.search import run_fit
    from fabric_optics.fitting.spec import parse_free
    from fabric_optics.paths import toml_dumps
    from gonio.data import in_plane_geometry, make_dataset, new_meta
    from simulate.config import load_config, parse_config

    wl = np.arange(480.0, 581.0, 20.0)
    rows = []
    for theta_i in (0.0, 30.0):
        for s in (-40.0, -20.0, -10.0, 10.0, 20.0, 40.0):
            if abs(s + theta_i) >= 5.0 and abs(in_plane_geometry(theta_i, np.array([s]))[0][0]) <= 45.0:
                to, po = in_plane_geometry(theta_i, np.array([s]))
                rows.append((theta_i, 0.0, float(to[0]), float(po[0])))
    import pandas as pd

    geometries = pd.DataFrame(rows, columns=["theta_i", "phi_i", "theta_o", "phi_o"])

    def dataset(beta: np.ndarray, noise_seed: int | None, at: pd.DataFrame = geometries):
        """A measured dataset of the ``at`` geometries with ``beta`` (mock noise from ``noise_seed`` when given)."""
        u = 0.011 * np.abs(beta) + 1e-5
        if noise_seed is not None:
            beta = beta + np.random.default_rng(noise_seed).standard_normal(beta.shape) * u
        rep = at.loc[at.index.repeat(wl.size)].reset_index(drop=True)
        return make_dataset(dict(theta_i=rep["theta_i"], phi_i=rep["phi_i"], theta_o=rep["theta_o"],
                                 phi_o=rep["phi_o"], wavelength_nm=np.tile(wl, len(geometries)), beta=beta.ravel(),
                                 u_beta=u.ravel(), n=np.ones(beta.size, dtype=int)),
                            new_meta("measured", {"name": "synthetic ring dye"}))

    out = []
    for method, truth, start, target in (("classic", 1.0, 1.5, 0.1),
                                         ("summation", 2.5 * math.exp(-0.8), 2.5, 0.3)):
        if method not in methods:
            continue
        doc = tomllib.loads(load_config("red-cotton").text)
        doc["fiber"].update(dye_profile="ring", dye_depth_um=start)
        cfg = parse_config(toml_dumps(doc), "ring.toml")
        free = parse_free(["fiber.dye_depth_um"], cfg)
        t = time.perf_counter()
        made = FitProblem(cfg, dataset(np.full((len(geometries), wl.size), 0.3), None), free, method=method,
                          target_rel_err=target, seed=3, wavelengths_nm=wl)
        beta, _ = made.model(np.array([truth]))
        # the model's rows are the problem's geometries (in its order)
        problem = FitProblem(cfg, dataset(beta, 11, made.geometries), free, method=method, target_rel_err=target, seed=3,
                             wavelengths_nm=wl)
        problem.share_walks(made)
        result = run_fit(problem, noise_draws=16, max_evaluations=30)
        out.append({"method": method, "target_rel_err": target, "truth_um": truth, "start_um": start,
                    "fitted_um": float(result.x[0]), "u_um": float(result.u[0]),
                    "within_u": abs(float(result.x[0]) - truth) / float(result.u[0]),
                    "objective": result.objective, "objective_start": result.objective_start,
                    "walks": made.counters.walks + problem.counters.walks, "seconds": time.perf_counter() - t})
    if "mc" in methods:
        out.append(mc_fit(truth=3.0, start=1.2, target=0.2))
    return out


def mc_fit(truth: float, start: float, target: float) -> dict:
    """Fit a ring dye's depth by the felt Monte Carlo's fit from a measurement the felt Monte Carlo made.

    The green-felt preset with its dye in a ring; the measurement is one Monte Carlo run at ``truth`` (seed 4)
    with 1 % noise, its ``u_beta`` the run's and the noise's, at 6 wavelengths and the in-plane geometries of
    incidences 0 and 30 deg within 45 deg; the fit (4 Monte Carlo runs at most) starts at ``start``.

    Parameters
    ----------
    truth : float
        The depth the measurement is made at (um).
    start : float
        The fit's starting depth (um).
    target : float
        The Monte Carlo's target relative error.

    Returns
    -------
    dict
        As :func:`fits`'s entries, with the Monte Carlo runs in place of the walks.
    """
    import pandas as pd

    from fabric_optics.fitting import spacemapping as fit_mc
    from fabric_optics.fitting.spec import parse_free
    from fabric_optics.paths import toml_dumps
    from gonio.data import in_plane_geometry, make_dataset, new_meta
    from simulate.config import load_config, parse_config

    wl = np.arange(480.0, 581.0, 20.0)
    free = "fiber.dye_depth_um=0.3:6"

    def felt(depth: float):
        doc = tomllib.loads(load_config("green-felt").text)
        doc["fiber"].update(dye_profile="ring", dye_depth_um=depth)
        return parse_config(toml_dumps(doc), "felt-ring.toml")

    rows = []
    for theta_i in (0.0, 30.0):
        for s in (-40.0, -20.0, -10.0, 10.0, 20.0, 40.0):
            to, po = in_plane_geometry(theta_i, np.array([s]))
            if abs(s + theta_i) >= 5.0 and abs(to[0]) <= 45.0:
                rows.append((theta_i, 0.0, float(to[0]), float(po[0])))
    geometries = pd.DataFrame(rows, columns=["theta_i", "phi_i", "theta_o", "phi_o"])

    def dataset(beta: np.ndarray, u: np.ndarray, at: pd.DataFrame):
        rep = at.loc[at.index.repeat(wl.size)].reset_index(drop=True)
        return make_dataset(dict(theta_i=rep["theta_i"], phi_i=rep["phi_i"], theta_o=rep["theta_o"],
                                 phi_o=rep["phi_o"], wavelength_nm=np.tile(wl, len(at)), beta=np.ravel(beta),
                                 u_beta=np.ravel(u), n=np.ones(np.size(beta), dtype=int)),
                            new_meta("measured", {"name": "synthetic ring-dyed felt"}))

    t = time.perf_counter()
    flat = np.full((len(geometries), wl.size), 0.3)
    made = felt(truth)
    probe = fit_mc.MCFitProblem(made, dataset(flat, 0.01 * flat, geometries), parse_free([free], made),
                                target_rel_err=target, seed=4, wavelengths_nm=wl)
    ref = fit_mc.run_monte_carlo(probe, np.array([truth]))
    noise = np.random.default_rng(3).standard_normal(ref.beta.shape)
    measured = dataset(ref.beta * (1.0 + 0.01 * noise), np.sqrt(ref.u_beta ** 2 + (0.01 * ref.beta) ** 2) + 1e-5,
                       probe.geometries)
    cfg = felt(start)
    problem = fit_mc.MCFitProblem(cfg, measured, parse_free([free], cfg), target_rel_err=target, seed=4,
                                  wavelengths_nm=wl)
    result = fit_mc.run_mc_fit(problem, max_runs=4, noise_draws=16)
    return {"method": "mc", "target_rel_err": target, "truth_um": truth, "start_um": start,
            "fitted_um": float(result.x[0]), "u_um": float(result.u[0]),
            "within_u": abs(float(result.x[0]) - truth) / float(result.u[0]),
            "objective": result.objective, "objective_start": result.objective_start,
            "walks": int(result.info["mc_runs"]) + 1, "seconds": time.perf_counter() - t}


def main(argv: list[str] | None = None) -> None:
    """Run the three measurements and write them as JSON; print a line per result.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (``--json``, ``--shell-target``, ``--mc-target``, ``--methods``);
        ``sys.argv[1:]`` when None. An existing ``--json`` file is refused (argparse's exit 2).
    """
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--json", required=True, help="write the figures here")
    ap.add_argument("--shell-target", type=float, default=0.002)
    ap.add_argument("--mc-target", type=float, default=0.01)
    ap.add_argument("--methods", default="classic,summation,mc", help="the fits to run (comma-separated)")
    a = ap.parse_args(argv)
    if Path(a.json).exists():
        ap.error(f"--json {a.json}: exists; remove it first")
    report = {"command": "python docs/scripts/dye_depth_check.py " + " ".join(argv or []),
              "machine": f"{platform.machine()}, {__import__('os').cpu_count()} logical CPUs, {platform.system()}",
              "shell": shell(a.shell_target), "mc": against_mc(a.mc_target),
              "fits": fits(tuple(m.strip() for m in a.methods.split(",")))}
    Path(a.json).write_text(json.dumps(report, indent=1) + "\n")
    for r in report["shell"]:
        print(f"{r['profile']} {r['depth']}: mu {r['mu_per_radius']:.3f}: table {r['table']:.5f} +- {r['u_table']:.5f}, "
              f"closed form {r['closed_form']:.5f} (z {r['z']:+.2f}); uniform {r['uniform_closed_form']:.5f}")
    print("table against the ring dye's Monte Carlo, z:", np.round(report["mc"]["z"], 2).tolist())
    for f in report["fits"]:
        print(f"{f['method']}: {f['fitted_um']:.3f} +- {f['u_um']:.3f} um (truth {f['truth_um']:.3f}, start "
              f"{f['start_um']:.3f}; {f['within_u']:.2f} u), {f['walks']} {'runs' if f['method'] == 'mc' else 'walks'}, {f['seconds']:.0f} s")


if __name__ == "__main__":
    main()
