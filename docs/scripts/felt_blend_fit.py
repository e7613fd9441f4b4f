"""Fit the green felt by a blend of two dyed fibre populations and by one, in its colour and in another.

Does a blend of two differently dyed fibre populations, fitted by the summation, hold the green felt
better than one population? And does it transfer to another colour with the structure kept?

    gonio demo --sample fixtures/real/acrylic_felt_green_rgb.bsdf --plan measured --out DIR/measured
    python docs/scripts/felt_blend_fit.py DIR/measured --out DIR/fits --json DIR/felt-blend-fit.json

Four fits of the structured summation (``simulate fit --method summation``), from the ``green-felt`` preset's
structure, scatterers and surface (fitted to this felt once), only dyes (and shares) free:

* ``one``: the preset with its dye as 8 knots (``--dye knots --free dye``), the demo's dye refit;
* ``blend``: the same fiber in two populations of share 0.5, ``green`` with the preset's knots and ``yellow`` with
  the knots above 600 nm set to the 550 nm one (its red as clear as its green: a yellow-green fibre), both dyes and
  the share free (``--free populations.green.dye,populations.yellow.dye,populations.green.share``);
* ``one-permuted`` and ``blend-permuted``: the same fits of the measurement with its colour channels permuted
  (:func:`permute_channels`: R, G, B of the new measurement are B, R, G of the old: a blue felt of the same
  structure),
  the transfer to another colour with the structure kept.

For each: NRMSE, the colour differences (dh, ds) and the level ``k_Y`` of the fitted model (fit.json), and the
retro-ring ratio ``beta(6 deg) / beta(30 deg)`` at 27.76 and 40.03 deg, 550 and 650 nm
(:func:`compare.ratios.opposition_ratios` of the fitted model's dataset); the measurement's own beside them.

``--permute-only``: write the permuted measurement (``OUT/measured-permuted``, :func:`permute_channels`) and stop.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import tomllib
from pathlib import Path

import numpy as np

#: new R, G, B = old (B, R, G)
PERMUTATION = {"R": "B", "G": "R", "B": "G"}
INCIDENCES = (27.76, 40.03)
BANDS_NM = (550.0, 650.0)


def permute_channels(src: Path, dst: Path) -> Path:
    """The dataset at ``src`` with its colour channels permuted (:data:`PERMUTATION`), written to ``dst``.

    The imported dataset is the mock's spectral reading of the RGB file, ``beta = R b_R + G b_G + B b_B`` with the
    basis spectra of :mod:`gonio.mock.upsample`. Each geometry's ``(R, G, B)`` is recovered by least squares on the
    basis and the spectrum rebuilt from the permuted channels; what the basis does not hold (the acquisition's
    noise) is added back unchanged, and ``u_beta`` keeps its relative size. The geometry, the metadata and the rows'
    order are kept. An RGB dataset (``channel`` column) has its channels renamed.

    Parameters
    ----------
    src : pathlib.Path
        The dataset folder to read.
    dst : pathlib.Path
        The dataset folder to write; its sample's name says the channels are permuted.

    Returns
    -------
    pathlib.Path
        ``dst``.
    """
    from gonio.data import make_dataset, read_dataset, write_dataset
    from gonio.mock.upsample import basis

    ds = read_dataset(src)
    table = ds.table.copy()
    order = ["R", "G", "B"]
    take = [order.index(PERMUTATION[c]) for c in order]     # new channel k is old channel take[k]
    if "channel" in table.columns:
        inverse = {old: new for new, old in PERMUTATION.items()}
        table["channel"] = table["channel"].map(lambda c: inverse.get(c, c))
    else:
        keys = ["theta_i", "phi_i", "theta_o", "phi_o"]
        for _, rows in table.groupby(keys, sort=False):
            idx = rows.index.to_numpy()
            b = basis(rows["wavelength_nm"].to_numpy(float))                 # [L, 3]
            beta = rows["beta"].to_numpy(float)
            c, *_ = np.linalg.lstsq(b, beta, rcond=None)
            new = b @ c[take] + (beta - b @ c)
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(np.abs(beta) > 0, np.abs(new / beta), 1.0)
            table.loc[idx, "beta"] = new
            table.loc[idx, "u_beta"] = rows["u_beta"].to_numpy(float) * scale
    meta = dict(ds.meta)
    sample = dict(meta.get("sample") or {})
    sample["name"] = f"{sample.get('name', 'sample')} (channels permuted: new R, G, B = old B, R, G)"
    meta["sample"] = sample
    write_dataset(make_dataset(table, meta), dst)
    return dst


def blend_config(out: Path, wavelengths_nm) -> Path:
    """The ``blend`` start: green-felt with its dye as knots, in two populations (module docstring).

    Parameters
    ----------
    out : pathlib.Path
        Folder to write the config to (``green-felt-blend.toml``).
    wavelengths_nm : array_like
        The wavelengths at which the preset's dye becomes knots (the preset's own).

    Returns
    -------
    pathlib.Path
        The written config.
    """
    from fabric_optics.fitting.start import knots_config
    from fabric_optics.paths import toml_dumps
    from simulate.config import load_config

    base = knots_config(load_config("green-felt"), wavelengths_nm)
    doc = tomllib.loads(base.text)
    dye = doc["fiber"]["dye"]
    knots = np.asarray(dye["wavelength_nm"], float)
    green = [float(v) for v in dye["log10_per_um"]]
    at_550 = float(np.interp(550.0, knots, green))
    yellow = [at_550 if k > 600.0 else v for k, v in zip(knots, green, strict=True)]
    doc["name"] = "green-felt-blend"
    doc["populations"] = [
        {"name": "green", "share": 0.5, "fiber": {"dye": dict(dye, log10_per_um=green)}},
        {"name": "yellow", "share": 0.5, "fiber": {"dye": dict(dye, log10_per_um=yellow)}},
    ]
    path = out / "green-felt-blend.toml"
    path.write_text(toml_dumps(doc, header="# green-felt in two populations (docs/scripts/felt_blend_fit.py)"))
    return path


def ratios(dataset_dir: Path) -> dict:
    """The retro-ring ratios at :data:`INCIDENCES` and :data:`BANDS_NM` of a dataset.

    Parameters
    ----------
    dataset_dir : pathlib.Path
        The dataset folder.

    Returns
    -------
    dict
        ``{incidence: {band: ratio}}`` for each incidence the dataset holds within 0.05 deg, keyed as
        ``"27.76"`` and ``"550"``; ``{"missing": reason}`` when the dataset has no ring to read.
    """
    from compare.ratios import Missing, opposition_ratios
    from gonio.data import read_dataset

    found = opposition_ratios(read_dataset(dataset_dir).table)
    out: dict = {}
    if isinstance(found, Missing):
        return {"missing": found.reason}
    for ti in INCIDENCES:
        key = min(found, key=lambda t: abs(t - ti))
        if abs(key - ti) > 0.05:
            continue
        r = found[key]
        out[f"{ti:g}"] = {f"{int(w)}": float(r.value[w]) for w in BANDS_NM}
    return out


def run(args: argparse.Namespace) -> dict:
    """Permute the measurement, then run the four fits (or those of ``--only``) and gather their figures.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`main`).

    Returns
    -------
    dict
        The JSON document (name, command, machine, settings and one row per fit and per measurement);
        empty with ``--permute-only``.
    """
    from fabric_optics import api
    from simulate.provenance import machine

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    measured = Path(args.measured)
    permuted = permute_channels(measured, out / "measured-permuted")
    if args.permute_only:
        return {}
    from simulate.config import load_config

    wl = load_config("green-felt").wavelengths_nm
    blend = blend_config(out, wl)
    blend_free = "populations.green.dye,populations.yellow.dye,populations.green.share"
    fits = {
        "one": ("green-felt", measured, "dye", "knots"),
        "blend": (str(blend), measured, blend_free, "config"),
        "one-permuted": ("green-felt", permuted, "dye", "knots"),
        "blend-permuted": (str(blend), permuted, blend_free, "config"),
    }
    rows: dict = {"the measurement": {"ratios": ratios(measured)},
                  "the measurement permuted": {"ratios": ratios(permuted)}}
    for name, (config, data, free, dye) in fits.items():
        if args.only and name not in args.only.split(","):
            continue
        fit_dir = out / name
        budget = args.blend_max_evaluations if name.startswith("blend") else args.max_evaluations
        outcome = api.fit(config, data, free, fit_dir, method="summation", dye=dye, max_evaluations=budget,
                          target_rel_err=args.target_rel_err, threads=args.threads, force=True)
        doc = outcome.summary
        fitted = doc["fitted"]
        params = {p["name"]: {"value": p["value"], "u": p.get("u"), "u_status": p.get("u_status", "")}
                  for p in doc["parameters"] if p["name"].endswith("share")}
        rows[name] = {"free": free, "dye": dye, "nrmse": fitted["nrmse"], "dh": fitted.get("dh"),
                      "ds": fitted.get("ds"), "k_Y": fitted.get("level_k"),
                      "start": {k: doc["start"].get(k) for k in ("nrmse", "dh", "ds", "level_k")},
                      "shares": params, "evaluations": doc["info"]["evaluations"],
                      "seconds": doc["info"]["seconds"], "ratios": ratios(fit_dir / "fitted"),
                      "warnings": list(outcome.warnings)}
        print(f"{name}: NRMSE {fitted['nrmse']:.4f}, dh {fitted.get('dh', float('nan')):+.4f}, "
              f"ds {fitted.get('ds', float('nan')):+.4f}, k_Y {fitted.get('level_k') or float('nan'):.3g}",
              file=sys.stderr)
    return {"name": "felt-blend-fit",
            "command": ("gonio demo --sample fixtures/real/acrylic_felt_green_rgb.bsdf --plan measured --out MEASURED; "
                        "python " + " ".join(shlex.quote(a) for a in sys.argv)),
            "machine": machine(),
            "data": {"settings": {"method": "summation", "start": "green-felt", "max_evaluations": args.max_evaluations,
                                  "blend_max_evaluations": args.blend_max_evaluations,
                                  "target_rel_err": args.target_rel_err, "permutation": PERMUTATION,
                                  "incidences_deg": list(INCIDENCES), "bands_nm": list(BANDS_NM)},
                     "file_ratios_spectral": "docs/data/felt-blend-screen.json, row 'the file'",
                     "rows": rows}}


def main(argv: list[str] | None = None) -> int:
    """Run the fits and write their figures; with ``--only``, the JSON's other rows are kept.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (the measurement, ``--out``, ``--json``, the budgets, ``--only``,
        ``--permute-only``); ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0 (argparse exits 2 on a bad argument).
    """
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("measured", help="the imported measurement (gonio demo ... --plan measured)")
    ap.add_argument("--out", required=True, help="folder of the fits and the permuted measurement")
    ap.add_argument("--json", help="write the figures here")
    ap.add_argument("--max-evaluations", type=int, default=800, help="the one-population fits' budget")
    ap.add_argument("--blend-max-evaluations", type=int, default=2400,
                    help="the blends' budget (17 free parameters: a Jacobian costs 34 evaluations)")
    ap.add_argument("--target-rel-err", type=float, default=0.03)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--only", default="", help="comma-separated fits of: one, blend, one-permuted, blend-permuted")
    ap.add_argument("--permute-only", action="store_true")
    args = ap.parse_args(argv)
    doc = run(args)
    if args.json and doc:
        path = Path(args.json)
        if args.only and path.is_file():     # some fits again: the others' rows kept
            old = json.loads(path.read_text())
            doc["data"]["rows"] = {**old["data"]["rows"], **doc["data"]["rows"]}
            doc["command"] = f"{old['command']}; {doc['command']}"
        path.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
