"""The ingredient table of issue 19: which piece of fabric structure does what to the red cotton's colour.

``python -m fabric_optics.bench.structure [CONFIG] [--photons-per-row N] [--seed S]`` prints, at the report's
colour geometry (incidence 0, observation 10 deg on the mirror side, docs/physics.md section 7), the
colour (H, S, V, BLUE/RED, GREEN/RED on linear sRGB, D65) of the fabric summed over:

1. the carpet of top cells (the old summation, next-event route at 1 %);
2. the visible average of the fiber (flat warp and weft, no masking) -- docs/physics.md 6.1;
3. + masking and shadowing by the neighbouring fibers of a touching layer;
4. + the weave's yarn surface (crimp inclination and section curvature, :mod:`simulate.fabric.structure`);
5. + the yarns' twist (24 deg Z);
6. + the light returned from the fiber layers below (the interior closure, 6.3);
7. the same with the literature's yarn packing fraction 0.6 instead of touching fibers;

and the felt (nonwoven) for comparison, then the hue along the in-plane curve at 60 deg incidence.
Rows 2-7 share ONE exit table (same photons), so their differences are the structure's, not noise.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np

from gonio.data.colour import spectrum_colour
from simulate import fabric as fab
from simulate.fiber import farfield as FF
from simulate.fabric import fiberlayer as FL
from simulate.fabric import interior as IN
from simulate.fabric import structure as ST
from simulate.config import load_config, weave_from_config

WAVELENGTHS = np.arange(390.0, 711.0, 10.0)


def _row(name: str, beta: np.ndarray) -> dict:
    c = spectrum_colour(WAVELENGTHS, beta)
    return {"ingredient": name, "h": c.h, "s": c.s, "v": c.v, "blue_red": c.blue_red, "green_red": c.green_red}


def ingredient_table(config: str = "red-cotton", photons_per_row: int = 20_000, seed: int = 0,
                     threads: int | None = None) -> dict:
    """The rows (module docstring) and the 60-degree hue curve, with timings."""
    cfg = load_config(config)
    fiber = cfg.fiber(WAVELENGTHS)
    weave = weave_from_config(cfg)
    w_i, w_o = fab.directions_deg([0.0], [0.0]), fab.directions_deg([10.0], [180.0])
    t0 = time.perf_counter()
    pairs = fab.FiberPairs.from_directions(w_i, w_o)
    from simulate import fiber as fiber_mod

    est = fiber_mod.volume_brdf(fiber, pairs.w_in, pairs.w_out, WAVELENGTHS, target_rel_err=0.01, seed=seed,
                                threads=threads)
    r_b = est.R + fiber_mod.surface_brdf(fiber, pairs.w_in, pairs.w_out)[:, None]
    rows = [_row("top-cell carpet (old summation)", fab.summation_from_table(pairs, r_b)[0][0])]
    table = FF.exit_table(fiber, WAVELENGTHS, photons_per_row=photons_per_row, seed=seed, threads=threads)
    t_table = time.perf_counter() - t0
    flat0 = ST.StructureSpec(yarn_surface=False, warp_twist_deg=0.0, weft_twist_deg=0.0)
    n_layers = max(1, round(weave.height_um / fiber.radius_um))
    cache: dict = {}

    def layer(masking: bool, interior: bool, packing: float = ST.CLOSE_PACKING) -> FL.LayerTable:
        key = (masking, interior, packing)
        if key not in cache:
            ratio = math.sqrt(ST.CLOSE_PACKING / packing)
            inner = IN.interior(table, fiber, n_layers, spacing_ratio=ratio) if interior else None
            cache[key] = FL.layer_table(table, fiber, masking=masking, spacing_ratio=ratio, interior=inner)
        return cache[key]

    steps = [
        ("visible average (flat, no masking)", flat0, False, False, ST.CLOSE_PACKING),
        ("+ masking/shadowing (touching layer)", flat0, True, False, ST.CLOSE_PACKING),
        ("+ yarn surface (crimp, section)", dataclasses.replace(flat0, yarn_surface=True), True, False,
         ST.CLOSE_PACKING),
        ("+ twist 24 deg Z", ST.StructureSpec(), True, False, ST.CLOSE_PACKING),
        (f"+ interior return ({n_layers} layers)", ST.StructureSpec(), True, True, ST.CLOSE_PACKING),
        ("  with packing fraction 0.6", ST.StructureSpec(packing_fraction=0.6), True, True, 0.6),
        ("felt (spread 20 deg, interior)", ST.StructureSpec(kind="nonwoven"), True, True, ST.CLOSE_PACKING),
    ]
    for name, spec, masking, interior, packing in steps:
        beta = ST.fabric_beta_from_G(layer(masking, interior, packing), ST.facets_for(spec, weave), w_i, w_o)[0]
        rows.append(_row(name, beta))
    s = np.arange(-60.0, 71.0, 10.0)
    beta60 = ST.fabric_beta_from_G(layer(True, True), ST.facets_for(ST.StructureSpec(), weave),
                                   fab.directions_deg(np.full(s.size, 60.0), np.zeros(s.size)),
                                   fab.directions_deg(np.abs(s), np.where(s >= 0, 180.0, 0.0)))
    curve = [{"s_deg": float(a), **_row("", b)} for a, b in zip(s, beta60)]
    return {"rows": rows, "curve60": curve, "exit_table_seconds": t_table, "seconds": time.perf_counter() - t0,
            "photons": int(table.photons + est.photons), "layers": n_layers}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m fabric_optics.bench.structure", description=__doc__.splitlines()[0])
    p.add_argument("config", nargs="?", default="red-cotton")
    p.add_argument("--photons-per-row", type=int, default=20_000)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    out = ingredient_table(args.config, args.photons_per_row, args.seed)
    print("| ingredient | H | S | V | BLUE/RED | GREEN/RED |\n|---|---|---|---|---|---|")
    for r in out["rows"]:
        print(f"| {r['ingredient']} | {r['h']:.3f} | {r['s']:.3f} | {r['v']:.3f} | {r['blue_red']:.3f} | "
              f"{r['green_red']:.3f} |")
    print("\n60 deg incidence, in-plane: s (deg) -> H, S")
    print("  ".join(f"{c['s_deg']:+.0f}: {c['h']:.3f}/{c['s']:.2f}" for c in out["curve60"]))
    print(f"\n{out['photons']} photons, exit table {out['exit_table_seconds']:.0f} s, all {out['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
