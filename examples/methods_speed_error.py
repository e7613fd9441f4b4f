"""Red cotton by three fabric models: what each costs and how far it is from the Monte Carlo.

The Monte Carlo ray tracing of the woven fabric is the reference; the summation over the fabric's
fibers and the classic Lambert + Cook-Torrance model are cheaper. For each model the script prints
its wall time and its departure from the reference (NRMSE after normalising both at the normal, as
``compare`` does), with the reference's own Monte Carlo error beside it.

    python examples/methods_speed_error.py [--target-rel-err 0.03] [--plan red-cotton] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time

import fabric_optics as fo


def main(argv: list[str] | None = None) -> int:
    """Simulate red cotton by the three models, time each, and print each one's error against the Monte Carlo.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (``--target-rel-err``, ``--plan``, ``--json``); ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0 (argparse exits 2 on a bad argument).
    """
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--target-rel-err", type=float, default=0.03)
    ap.add_argument("--plan", default="red-cotton")
    ap.add_argument("--json", default=None, help="also write the figures as JSON here")
    args = ap.parse_args(argv)

    runs = {}
    for method in ("mc", "summation", "classic"):
        t0 = time.perf_counter()
        runs[method] = fo.simulate("red-cotton", plan=args.plan, method=method, target_rel_err=args.target_rel_err,
                                   seed=1)
        runs[method].meta["wall_seconds"] = time.perf_counter() - t0

    reference = runs.pop("mc")
    comparison = fo.compare(reference, [runs["summation"], runs["classic"]])
    rows = [{"method": "mc", "seconds": reference.meta["wall_seconds"], "nrmse_vs_mc": 0.0,
             "rel_err": reference.meta["provenance"]["rel_err"]}]
    for (name, ds), sim_name in zip(runs.items(), comparison.simulated, strict=True):
        rows.append({"method": name, "seconds": ds.meta["wall_seconds"],
                     "nrmse_vs_mc": comparison.overall[sim_name].nrmse,
                     "rel_err": ds.meta["provenance"].get("rel_err")})
    print(f"{'method':<10} {'seconds':>8} {'NRMSE vs mc':>12} {'own error':>10}")
    for r in rows:
        own = "-" if r["rel_err"] is None else f"{r['rel_err']:.2%}"
        print(f"{r['method']:<10} {r['seconds']:8.2f} {r['nrmse_vs_mc']:12.4f} {own:>10}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump({"plan": args.plan, "target_rel_err": args.target_rel_err, "runs": rows}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
