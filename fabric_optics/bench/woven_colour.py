"""The red cotton's colour by the woven Monte Carlo with the yarns' twist, against the structured summation (issue 19).

``python -m fabric_optics.bench.woven_colour [CONFIG] [--target 0.01] [--seed S] [--threads N]`` prints, at the
report's colour geometry (incidence 0, observation 10 deg on the mirror side, as
:mod:`fabric_optics.bench.structure`), the colour (H, S, V, BLUE/RED, GREEN/RED on linear sRGB, D65) of:

1. the woven Monte Carlo as it was: the yarn a tube (Cook-Torrance about the tube's normal) with the
   FIBER's table scaled to it, fibers along the yarn axis (twist 0);
2. the same with the ``[structure]`` twist (default 24 deg Z, both systems);
3. + the yarn's surface made of fibers (:class:`simulate.woven.FiberSurface`, ``surface="fibers"``) --
   rows 1-3 share ONE pair of fiber tables, so their differences are the twist's and the surface's;
4. + the yarn's volume the pile of its fibers (:mod:`simulate.woven.pile`; its own pair of tables):
   the Monte Carlo of ``simulate fabric CONFIG --method mc`` with a woven ``[structure]``; and the pile
   with the tube's own surface (the two ingredients' order: each one's share without the other);
5. the structured summation (:func:`simulate.fabric.structure.structured_beta`) of the same structure;

(a felt, ``kind = "nonwoven"``: the felt Monte Carlo of :mod:`simulate.woven.felt` instead of rows 1-4);

and, with ``--surface-only``, the surface term alone at that geometry (``beta`` of a volume that returns
nothing: the tables' rows zeroed) of the tube, of the yarn surface made of fibers, and of the structured
summation (its layer table with the surface part only, :func:`simulate.fabric.fiberlayer.surface_table`).

with each run's seconds. The config's ``[structure]`` is used if it has one, else the defaults
(``kind = "woven"``).
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

from gonio.data.colour import spectrum_colour
from simulate import fabric as fab
from simulate import woven as W
from simulate.config import load_config, weave_from_config
from simulate.fabric import structure as ST
from simulate.fabric.mesh import mesh as weave_mesh

WAVELENGTHS = np.arange(390.0, 711.0, 10.0)


def _row(name: str, beta: np.ndarray, seconds: float) -> dict:
    c = spectrum_colour(WAVELENGTHS, beta)
    return {"model": name, "h": c.h, "s": c.s, "v": c.v, "blue_red": c.blue_red, "green_red": c.green_red,
            "seconds": seconds}


def colours(config: str = "red-cotton", target: float = 0.01, seed: int = 0, threads: int | None = None) -> list[dict]:
    cfg = load_config(config)
    spec = cfg.structure if getattr(cfg, "structure", None) is not None else ST.StructureSpec()
    fiber = cfg.fiber(WAVELENGTHS)
    mesh: Any
    if spec.kind == "nonwoven":
        from simulate.woven.felt import felt_mesh

        wv, mesh = None, felt_mesh(spec, float(fiber.radius_um), seed=seed)
    else:
        wv = weave_from_config(cfg)
        mesh = weave_mesh(wv)
    w_i, w_o = fab.directions_deg([0.0], [0.0]), fab.directions_deg([10.0], [180.0])
    t0 = time.perf_counter()
    half = W.table_photons(target) // 2
    tables = (W.yarn_table(fiber, WAVELENGTHS, photons_per_row=half, seed=seed, threads=threads),
              W.yarn_table(fiber, WAVELENGTHS, photons_per_row=half, seed=seed + 1_000_003, threads=threads))
    t_tables = time.perf_counter() - t0
    rows = []
    twist = f"twist {spec.warp_twist_deg:g} {spec.warp_twist}/{spec.weft_twist_deg:g} {spec.weft_twist}"
    runs: list[tuple[str, Any, str | None, Any]] = [("felt MC", spec, None, tables)] if wv is None else [
        ("woven MC: tube, fiber table, twist 0", None, "tube", tables),
        (f"woven MC: tube, fiber table, {twist}", spec, "tube", tables),
        ("+ yarn surface made of fibers", spec, "fibers", tables),
        ("+ yarn volume the fibers' pile", spec, "fibers", None),
        ("(the pile with the tube's surface)", spec, "tube", None)]
    for name, st, surface, tabs in runs:
        t = time.perf_counter()
        beta, u, info = W.fabric_beta(mesh, fiber, w_i, w_o, WAVELENGTHS, target_rel_err=target, seed=seed,
                                      threads=threads or 1, tables=tabs, structure=st, surface=surface)
        row = _row(name, beta[0], time.perf_counter() - t)
        row["rel_err"] = info["incidences"][0]["rel_err"]
        rows.append(row)
    t = time.perf_counter()
    beta, u, info = ST.structured_beta(spec, fiber, wv, w_i, w_o, WAVELENGTHS, target_rel_err=target, seed=seed,
                                       threads=threads)
    rows.append(_row("structured summation", beta[0], time.perf_counter() - t))
    rows[0]["tables_seconds"] = t_tables
    return rows


def surface_only(config: str = "red-cotton", target: float = 0.02, seed: int = 0) -> dict:
    """The surface term's ``beta`` (grey: the same at every wavelength) at the colour geometry, three ways."""
    import dataclasses

    from simulate.fabric import fiberlayer as FL

    cfg = load_config(config)
    spec = cfg.structure if getattr(cfg, "structure", None) is not None else ST.StructureSpec()
    wl = np.array([550.0])
    fiber = cfg.fiber(wl)
    wv = weave_from_config(cfg)
    mesh = weave_mesh(wv)
    w_i, w_o = fab.directions_deg([0.0], [0.0]), fab.directions_deg([10.0], [180.0])
    tabs = W.table_halves(fiber, wl, 2000, seed, 1)
    dark = (dataclasses.replace(tabs[0], T=np.zeros_like(tabs[0].T)), dataclasses.replace(tabs[1], T=np.zeros_like(tabs[1].T)))
    out = {}
    for surf in ("tube", "fibers"):
        b, u, _ = W.fabric_beta(mesh, fiber, w_i, w_o, wl, target_rel_err=target, seed=seed, tables=dark,
                                structure=spec, surface=surf)
        out[surf] = (float(b[0, 0]), float(u[0, 0]))
    G = FL.surface_table(float(fiber.roughness), float(fiber.n_host), True, spec.spacing_ratio)
    # surface_table's default grid (7.5 deg in theta, 15 deg in phi), as fiberlayer's LayerTable
    th = np.arange(0.0, 90.0 + 1e-9, 7.5)
    ph_i = np.arange(0.0, 90.0 + 1e-9, 15.0)
    ph_o = np.arange(0.0, 360.0 + 1e-9, 15.0)
    lt = FL.LayerTable(th, ph_i, th, ph_o, np.ascontiguousarray(G[..., None]), True, spec.spacing_ratio)
    out["summation"] = (float(ST.fabric_beta_from_G(lt, ST.facets_for(spec, wv), w_i, w_o)[0, 0]), 0.0)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", nargs="?", default="red-cotton")
    ap.add_argument("--target", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--surface-only", action="store_true", help="only the surface term's beta, three ways")
    a = ap.parse_args(argv)
    if a.surface_only:
        for name, (b, u) in surface_only(a.config, a.target, a.seed).items():
            print(f"surface term alone, {name:10s} beta {b:.4f}" + (f" +- {u:.4f}" if u else ""))
        return
    rows = colours(a.config, a.target, a.seed, a.threads)
    print(f"{a.config}: incidence 0, observation 10 deg (mirror side); BSSRDF tables "
          f"{rows[0]['tables_seconds']:.0f} s")
    print(f"{'model':40s} {'H':>6s} {'S':>6s} {'V':>6s} {'B/R':>6s} {'G/R':>7s} {'s':>6s}")
    for r in rows:
        print(f"{r['model']:40s} {r['h']:6.3f} {r['s']:6.3f} {r['v']:6.3f} {r['blue_red']:6.3f} "
              f"{r['green_red']:7.4f} {r['seconds']:6.0f}" + (f"  (rel. err {r['rel_err']:.3f})" if "rel_err" in r else ""))


if __name__ == "__main__":
    main()
