r"""``simulate fit``: fit named config parameters of a fabric model to a measurement (the inverse problem).

``simulate fit CONFIG MEASURED_DIR --free NAME[=LOW:HIGH],... --out DIR [--method summation|classic]``

Parameters
----------
A free parameter is a numeric field of the config, named by its dotted TOML path with list
indices (``particles.volume_fraction``, ``particles.size.median_radius_um``,
``surface.rms_slope``, ``fiber.dye.bands[0].peak_per_um``, ``fiber.dye.edge_nm``, ...), or an
alias: ``volume_fraction``, ``radius`` (the particle radius or median radius), ``rms_slope``,
``dye`` (every coefficient of the config's smooth dye curve: baseline, band centres, widths and
peaks, or the logistic edge's four), ``dye-peaks`` (only the dye's amplitudes: baseline and peaks,
or short/long). Bounds default per kind (:func:`default_bounds`); explicit ``=LOW:HIGH`` wins.
The dye must be a named smooth curve (``gaussian-bands``/``logistic-edge``): a few coefficients
describe a smooth spectrum, a free table would be an ill-posed fit of 30 values.

Objective (weights)
-------------------
Exactly the figures ``compare`` reports: per evaluation the model is written as a dataset at the
measured geometries (only those: the normal/normal value of both is estimated alike) and
:func:`compare.comparison.compare_datasets` normalises it at the normal direction and computes the
overall curve error and the colour match (no re-implementation). The residual vector is::

    r = [ (k C_j - beta_meas,j) / (mean(beta_meas) sqrt(N)) ]_j  ++  sqrt(w_c) [dh, ds]

so ``F = |r|^2 = NRMSE^2 + w_c (dh^2 + ds^2)``: the overall NRMSE squared plus the hue
difference (turns, on the circle) and saturation difference squared at compare's colour
geometry, with ``w_c = 1`` by default (``--colour-weight``). With ``w_c = 1`` a hue error of
0.01 turn (3.6 deg) costs as much as 1 % NRMSE: both are just noticeable. V is left out: it is
set by the luminance scale ``k_Y`` (and undefined for relative measurements); a photometric
measurement has no colour terms.

Monte Carlo noise
-----------------
Only the particles / fiber geometry need photons to be walked. Every walk uses the same seeds
per (incident direction, wavelength group) and, after the first (accuracy-controlled) one, the
same photon counts: common random numbers, so the objective is a smooth function of the
parameters up to rare discrete events, not a fresh noise sample per evaluation. The dye is
re-weighted, never walked: every walk stores the volume term at 16 host absorptions per
wavelength (:mod:`simulate.fiber.absorption`) and any dye spectrum is read from that table, so a
dye-only fit walks photons once; the surface RMS slope enters through the analytic
Cook-Torrance term only. Finite-difference Jacobians: central, step 10^-3 of the bound range, for
dye and surface parameters (the table is C1); forward, step 10 % of the value, for walked
parameters. Common random numbers reduce but do not remove the Monte Carlo noise of a re-walked
objective (a change of mu_s moves every photon path): measured on red cotton's volume fraction at
5 % photon error, a 3 % step gave a slope of the wrong sign (the noise), 10 % the trend, and the
walked-parameter recovery test converges with it.

Optimiser
---------
``scipy.optimize.least_squares`` (trust-region reflective, bounded) in coordinates scaled to
``[0, 1]`` by the bounds: the objective is a sum of squares with a cheap exact structure and
few parameters, where Gauss-Newton converges in a handful of Jacobians -- decisive when a
Jacobian costs a walk per scattering parameter. Band centres and edges can make it multimodal
(a band can slide to either side of a spectral feature): ``--starts N`` adds N-1 Latin-hypercube
starts (``scipy.stats.qmc``) inside the bounds and keeps the best -- cheap for dye-only fits,
where no photon is walked; a global evolutionary method would spend thousands of evaluations,
which a walked parameter cannot afford.

Uncertainties
-------------
Linear propagation at the solution with the Jacobian ``J`` (``dp = -J^+ dr``): the measurement's
``u_beta`` by sampling 64 noise draws of the measured dataset, each run through the whole
objective (normalisation and colour included, so their correlations are exact to first order),
and the model's Monte Carlo standard error the same way (table values perturbed by their
standard errors, per output and wavelength). ``u`` = square root of the diagonal of the summed
covariance; correlations from it. A parameter is flagged not identifiable when the scaled
Jacobian has a flat direction (singular value below 10^-3 of the largest: the direction is
named) or its uncertainty exceeds half its bound range.

Interrupt and resume
--------------------
The last accepted point (the best objective so far: trust-region steps are accepted only when
they lower it) is written atomically to ``DIR/fit-state.json`` after every improvement, with the
photon counts; ``--resume`` starts from it (refused when the config, measurement, method or
free parameters differ). Ctrl-C leaves that state behind (exit 130).

Outputs in DIR: ``fitted.toml`` (the fitted config, ready for ``simulate fabric``),
``initial/`` and ``fitted/`` (datasets of the model at the start and the fitted parameters, at
the measured geometries), ``report/`` (``compare report`` of measurement vs initial vs fitted),
``fit.json`` (parameters, uncertainties, correlations, objective, warnings, evaluations, walks,
times) and ``fit-state.json``.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import logging
import math
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd

from gonio.data.dataset import COLUMNS, Dataset, make_dataset, new_meta
from simulate import fabric as fab
from simulate import fiber as fib
from simulate.config import SimulationConfig, parse_config
from studies import paths
from studies.paths import toml_dumps
from simulate.fiber.absorption import DEFAULT_NODES, AbsorptionTable, absorption_nodes, absorption_table

__all__ = [
    "FitError",
    "FreeParameter",
    "FitProblem",
    "FitResult",
    "GENERATOR",
    "STATE_NAME",
    "default_bounds",
    "parse_free",
    "run_fit",
    "toml_dumps",
    "write_outputs",
]

log = logging.getLogger(__name__)

GENERATOR = "simulate fit"
STATE_NAME = "fit-state.json"
STATE_SCHEMA = "simulate-fit-state/1"
_NOISE_DRAWS = 64
_FLAT = 1e-3
_WALK_STEP = 0.10
_CHEAP_STEP = 1e-3


class FitError(ValueError):
    """A fit that cannot start (bad parameter, bounds, measurement): one line, exit 2."""


# ------------------------------------------------------------------------------------------
# free parameters


@dataclass(frozen=True)
class FreeParameter:
    """One free config field: its dotted path, kind and bounds.

    ``kind``: ``"dye"`` (re-weighted from the absorption table), ``"surface"`` (analytic
    Cook-Torrance term) or ``"walk"`` (changes the scattering: photons are walked again).
    """

    name: str
    start: float
    low: float
    high: float
    kind: str


def _kind(path: str) -> str:
    if path.startswith("fiber.dye"):
        return "dye"
    if path == "surface.rms_slope":
        return "surface"
    return "walk"


def default_bounds(path: str, start: float) -> tuple[float, float]:
    """Default bounds of a free parameter from its field and start value.

    Volume fraction ``[start/5, min(5 start, 0.5)]``; radii and widths ``[start/4, 4 start]``;
    RMS slope ``[0.02, 0.5]``; dye amplitudes (``*_per_um``) ``[0, max(4 start, 0.01)]``; band
    centres and edges ``start -+ 60 nm``; log-normal ``sigma_g`` ``[1, 3]``; anything else
    ``[start/4, 4 start]`` (give ``=LOW:HIGH`` for a field that is 0).
    """
    leaf = path.rsplit(".", 1)[-1]
    if leaf == "volume_fraction":
        return start / 5.0, min(5.0 * start, 0.5)
    if path == "surface.rms_slope":
        return 0.02, 0.5  # Cook-Torrance's single-scattering domain (simulate.optics.microfacet warns above)
    if leaf.endswith("_per_um") and path.startswith("fiber.dye"):
        return 0.0, max(4.0 * start, 0.01)
    if leaf in ("center_nm", "edge_nm"):
        return start - 60.0, start + 60.0
    if leaf == "sigma_g":
        return 1.0, 3.0
    return start / 4.0, 4.0 * start


def parse_free(specs: list[str], config: SimulationConfig) -> list[FreeParameter]:
    """Free parameters from ``NAME[=LOW:HIGH]`` items (comma-separated in each string).

    Raises
    ------
    FitError
        An unknown name (the config has no such numeric field), malformed or empty bounds, bounds
        that exclude the start value, or a parameter named twice.
    """
    import tomllib

    data = tomllib.loads(config.text)
    out: list[FreeParameter] = []
    for spec in ",".join(specs).split(","):
        spec = spec.strip()
        if not spec:
            continue
        name, _, bounds = spec.partition("=")
        try:
            names = paths.expand(name.strip(), data)
            for path in names:
                paths.split(path)
        except paths.PathError as exc:
            raise FitError(f"--free {exc}" if name.strip() in paths.ALIASES else f"--free: {exc}") from None
        for path in names:
            try:
                start = paths.get(data, path)
            except KeyError:
                candidates = ", ".join(sorted(set(paths.numeric_leaves(data, "")) - {"seed"})[:12])
                raise FitError(f"--free: unknown parameter {path!r}: the config {config.name} has no such "
                               f"numeric field (fields: {candidates}, ...; aliases: volume_fraction, radius, "
                               "rms_slope, dye, dye-peaks)") from None
            if isinstance(start, bool) or not isinstance(start, (int, float)):
                raise FitError(f"--free: {path!r} is not a number in the config (a table or text); "
                               "free one numeric field")
            if path.startswith(("method.", "wavelengths.", "weave.")) or path == "seed":
                raise FitError(f"--free: {path!r} is a run setting, not an optical parameter")
            start = float(start)
            if bounds:
                lo_text, sep, hi_text = bounds.partition(":")
                try:
                    low, high = float(lo_text), float(hi_text)
                except ValueError:
                    low = high = math.nan
                if not sep or not (math.isfinite(low) and math.isfinite(high)) or not low < high:
                    raise FitError(f"--free: {spec!r}: bounds must be LOW:HIGH with LOW < HIGH, got {bounds!r}")
            else:
                low, high = default_bounds(path, start)
            if not low <= start <= high:
                raise FitError(f"--free: {path} = {start:g} in the config lies outside its bounds "
                               f"[{low:g}, {high:g}]; widen the bounds or change the config")
            if any(p.name == path for p in out):
                raise FitError(f"--free: {path} is named twice")
            out.append(FreeParameter(path, start, float(low), float(high), _kind(path)))
    if not out:
        raise FitError("--free: no parameter to fit")
    return out


# ------------------------------------------------------------------------------------------
# the problem: model evaluation and objective


def _model_geometries(measured: Dataset) -> pd.DataFrame:
    # exactly the measured geometries: compare then estimates the model's normal/normal value from
    # the same neighbours as the measurement's, so the estimate's own bias cancels in k(lambda)
    # (the model's exact normal value against an estimated measured one biased the fit)
    g = measured.table[["theta_i", "phi_i", "theta_o", "phi_o"]].drop_duplicates()
    return g.reset_index(drop=True)


def _dye_ceiling(config: SimulationConfig, free: list[FreeParameter], wl: np.ndarray) -> float:
    """Largest host absorption (1/um) any dye within the bounds can reach (the table's nu_max)."""
    if config.dye is None:
        return 1e-3
    p = copy.deepcopy(config.dye.params)
    doc = {"fiber": {"dye": p}}
    for f in free:
        if f.kind == "dye":
            paths.set_value(doc, f.name, f.high if f.name.endswith("_per_um") else paths.get(doc, f.name))
    if config.dye.curve == "gaussian-bands":
        top = p["baseline_per_um"] + sum(b["peak_per_um"] for b in p["bands"])
    elif config.dye.curve == "logistic-edge":
        top = max(p["short_per_um"], p["long_per_um"])
    else:
        top = float(np.max(config.dye(wl)))
    return max(1.05 * top, 1e-3)


@dataclass
class FitProblem:
    """Everything an evaluation needs: measurement, config, model, free parameters, settings."""

    config: SimulationConfig
    measured: Dataset
    free: list[FreeParameter]
    method: str = "classic"
    colour_weight: float = 1.0
    target_rel_err: float = 0.03
    seed: int | None = None
    threads: int | None = None
    wavelengths_nm: np.ndarray | None = None
    nodes: int = DEFAULT_NODES
    walks: int = 0
    walk_seconds: float = 0.0
    evaluations: int = 0
    photons: dict | None = None
    _tables: dict = field(default_factory=dict)
    _doc: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        import tomllib

        if self.method not in ("classic", "summation"):
            raise FitError(f"--method must be classic or summation, got {self.method!r}")
        if self.method == "summation" and self.config.method == "bssrdf":
            raise FitError("the summation fit needs the nee or beam fiber route (method.method in the config)")
        self._doc = tomllib.loads(self.config.text)
        if self.seed is None:
            self.seed = self.config.seed
        if self.wavelengths_nm is None:
            spectral = "channel" not in self.measured.table.columns
            self.wavelengths_nm = (np.asarray(self.measured.wavelengths_nm, float) if spectral
                                   else np.asarray(self.config.wavelengths_nm, float))
        self.wavelengths_nm = np.asarray(self.wavelengths_nm, float)
        self.geometries = _model_geometries(self.measured)
        g = self.geometries
        self.w_i = fab.directions_deg(g["theta_i"].to_numpy(), g["phi_i"].to_numpy())
        self.w_o = fab.directions_deg(g["theta_o"].to_numpy(), g["phi_o"].to_numpy())
        if np.any(g["theta_i"].to_numpy() >= 90.0):
            raise FitError("the measurement has incidences at or beyond 90 deg, which no fabric model evaluates")
        if self.method == "summation":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self.pairs = fab.FiberPairs.from_angles(g["theta_i"], g["phi_i"], g["theta_o"], g["phi_o"])
        self.nu_max = _dye_ceiling(self.config, self.free, self.wavelengths_nm)
        self.low = np.array([p.low for p in self.free])
        self.high = np.array([p.high for p in self.free])
        self.start = np.array([p.start for p in self.free])

    # -- parameters and configs ------------------------------------------------------------

    def config_at(self, x: np.ndarray) -> SimulationConfig:
        """The config with the free fields set to ``x`` (validated by the config parser)."""
        doc = copy.deepcopy(self._doc)
        for p, v in zip(self.free, x):
            paths.set_value(doc, p.name, float(v))
        return parse_config(toml_dumps(doc), f"{self.config.name}.toml", source=f"fit of {self.config.source}")

    def fitted_toml(self, x: np.ndarray, note: str) -> str:
        """TOML text of the fitted config (comments of the original are not kept)."""
        doc = copy.deepcopy(self._doc)
        for p, v in zip(self.free, x):
            paths.set_value(doc, p.name, float(v))
        doc["name"] = f"{self.config.name}-fitted"
        return toml_dumps(doc, header="\n".join("# " + line for line in note.splitlines()))

    # -- the model ----------------------------------------------------------------------------

    def _table(self, config: SimulationConfig) -> AbsorptionTable:
        walk = tuple(round(float(paths.get(self._doc_of(config), p.name)), 12) for p in self.free if p.kind == "walk")
        if walk in self._tables:
            return self._tables[walk]
        wl = self.wavelengths_nm
        nodye = dataclasses.replace(config, dye=None).fiber(wl)
        if self.method == "classic":
            w_in = np.array([[0.0, 0.0, 1.0]])
            outputs = fib.range_outputs([0.0], [1.0], [-math.pi], [math.pi], nodye.half_width)
            route = "beam"
        else:
            w_in = self.pairs.w_in
            outputs = fib.point_outputs(self.pairs.w_out, nodye.half_width)
            route = self.config.method
        table = absorption_table(nodye, w_in, outputs, wl, absorption_nodes(self.nu_max, self.nodes), method=route,
                                 target_rel_err=self.target_rel_err, photons=self.photons, seed=int(self.seed or 0),
                                 threads=self.threads)
        if self.photons is None:
            self.photons = dict(table.photons)
        self.walks += 1
        self.walk_seconds += table.seconds
        if len(self._tables) >= 4:  # the centre and a Jacobian's columns
            self._tables.pop(next(iter(self._tables)))
        self._tables[walk] = table
        return table

    def _doc_of(self, config: SimulationConfig) -> dict:
        import tomllib

        return tomllib.loads(config.text)

    def model(self, x: np.ndarray, mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``beta, u_beta`` ``[G, L]`` of the model at the model geometries for parameters ``x``.

        ``mc_noise`` (``[P, L]`` standard normal draws) shifts the volume term by that many
        standard errors (the uncertainty propagation of the Monte Carlo error).
        """
        config = self.config_at(x)
        table = self._table(config)
        wl = self.wavelengths_nm
        mu_host = config.dye(wl) if config.dye is not None else np.zeros(wl.size)
        R, u = table(mu_host)
        if mc_noise is not None:
            R = R + u * mc_noise
        with warnings.catch_warnings():
            # the domain warnings (RMS slope > 0.5, grazing) are the config's business, not once per evaluation
            warnings.simplefilter("ignore")
            return self._surface(config, R, u)

    def _surface(self, config: SimulationConfig, R: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.method == "classic":
            rho = R[0] * math.pi
            beta = fab.classic_beta(rho, self.w_i, self.w_o, config.rms_slope, config.n_host)
            u_beta = np.broadcast_to(u[0] * math.pi, beta.shape).copy()
        else:
            from simulate.media.medium import HGMedium

            surface_fiber = fib.Fiber(config.radius_um, config.n_host, HGMedium(mu_s=0.0, mu_a=0.0, g=0.0),
                                      config.rms_slope, config.cell_width_deg)
            r_surf = np.asarray(fib.surface_brdf(surface_fiber, self.pairs.w_in, self.pairs.w_out), float)
            beta, u_beta = fab.summation_from_table(self.pairs, R + r_surf[:, None], u)
        return beta, u_beta

    def dataset(self, beta: np.ndarray, u_beta: np.ndarray, label: str, extra: dict | None = None) -> Dataset:
        """The model values as a ``"simulated"`` dataset at the model geometries."""
        g = self.geometries
        wl = self.wavelengths_nm
        rep = g.loc[g.index.repeat(wl.size)].reset_index(drop=True)
        table = pd.DataFrame({"theta_i": rep["theta_i"], "phi_i": rep["phi_i"], "theta_o": rep["theta_o"],
                              "phi_o": rep["phi_o"], "wavelength_nm": np.tile(wl, len(g)),
                              "beta": np.asarray(beta).ravel(), "u_beta": np.asarray(u_beta).ravel(),
                              "n": np.ones(beta.size, dtype=np.int64)}, columns=list(COLUMNS))
        sample = dict(self.measured.meta.get("sample") or {})
        sample["name"] = f"{self.method} model ({label})"
        model = {"generator": GENERATOR, "name": f"fabric {self.method} ({label})", "method": self.method,
                 "config": self.config.name}
        return make_dataset(table, new_meta("simulated", sample, model, extra or {}))

    # -- the objective ----------------------------------------------------------------------

    def compare(self, sim: Dataset, measured: Dataset | None = None):
        """:func:`compare.comparison.compare_datasets` of the measurement and ``sim``."""
        from compare.comparison import compare_datasets

        logging.getLogger("compare").setLevel(logging.ERROR)  # per-evaluation chatter
        return compare_datasets(self.measured if measured is None else measured, [sim])

    def residuals_of(self, comparison) -> np.ndarray:
        """The residual vector of the module docstring from a comparison of one simulation."""
        name = next(iter(comparison.frames))
        frame = comparison.frames[name]
        meas = frame["beta_meas"].to_numpy(float)
        d = frame["beta_sim"].to_numpy(float) - meas
        parts = [d / (float(np.mean(meas)) * math.sqrt(d.size))]
        if comparison.colour is not None:
            c = comparison.colour.simulated[name]
            parts.append(math.sqrt(self.colour_weight) * np.array([c.dh, c.ds]))
        return np.concatenate(parts)

    def residuals(self, x: np.ndarray, measured: Dataset | None = None,
                  mc_noise: np.ndarray | None = None) -> np.ndarray:
        """Residuals at parameters ``x`` (physical units)."""
        beta, u = self.model(x, mc_noise)
        self.evaluations += 1
        return self.residuals_of(self.compare(self.dataset(beta, u, "trial"), measured))

    def precheck(self) -> None:
        """Everything the objective needs from the measurement, before any photon (FitError)."""
        from compare.errors import CompareError

        flat = np.full((len(self.geometries), self.wavelengths_nm.size), 0.5)
        try:
            self.compare(self.dataset(flat, 0.0 * flat, "check"))
        except CompareError as exc:
            raise FitError(f"the measurement cannot be fitted: {exc}") from None

    def identity(self) -> str:
        """Hash of what a resumed fit must share with the interrupted one."""
        doc = {"config": self.config.sha256, "measured": self.measured.meta.get("files", {}),
               "rows": len(self.measured), "method": self.method,
               "free": [[p.name, p.low, p.high] for p in self.free], "seed": self.seed,
               "wavelengths": self.wavelengths_nm.tolist(), "colour_weight": self.colour_weight}
        return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


# ------------------------------------------------------------------------------------------
# the fit


@dataclass
class FitResult:
    """A finished fit (see :func:`run_fit`)."""

    x: np.ndarray
    start: np.ndarray
    objective: float
    objective_start: float
    u: np.ndarray
    u_data: np.ndarray
    u_mc: np.ndarray
    correlation: np.ndarray
    warnings: list[str]
    info: dict


def _write_json_atomic(path: Path, doc: dict) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def load_state(out: Path, problem: FitProblem) -> dict | None:
    """The saved state of an interrupted fit of the same problem, or raise FitError."""
    path = out / STATE_NAME
    try:
        state = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise FitError(f"--resume: cannot read {path} ({exc})") from None
    if state.get("schema") != STATE_SCHEMA or state.get("identity") != problem.identity():
        raise FitError(f"--resume: {path} belongs to a different fit (config, measurement, method, seed or "
                       "free parameters differ); use a new --out or drop --resume")
    return state


def _jacobian(problem: FitProblem, x: np.ndarray, r0: np.ndarray, fun: Callable) -> np.ndarray:
    """d r / d x (physical units) by finite differences (steps in the module docstring)."""
    J = np.zeros((r0.size, x.size))
    for j, p in enumerate(problem.free):
        span = p.high - p.low
        if p.kind == "walk":
            h = max(_WALK_STEP * abs(x[j]), 1e-3 * span)
            if x[j] + h > p.high:
                h = -h
            J[:, j] = (fun(_with(x, j, x[j] + h)) - r0) / h
        else:
            h = _CHEAP_STEP * span
            lo, hi = max(x[j] - h, p.low), min(x[j] + h, p.high)
            J[:, j] = (fun(_with(x, j, hi)) - fun(_with(x, j, lo))) / (hi - lo)
    return J


def _with(x: np.ndarray, j: int, v: float) -> np.ndarray:
    y = x.copy()
    y[j] = v
    return y


def run_fit(problem: FitProblem, *, out: Path | None = None, resume: bool = False, max_evaluations: int = 60,
            starts: int = 1, progress: bool = False, noise_draws: int = _NOISE_DRAWS) -> FitResult:
    """Fit ``problem`` with ``scipy.optimize.least_squares`` (module docstring); state in ``out``."""
    from scipy.optimize import least_squares
    from tqdm import tqdm

    t0 = time.perf_counter()
    span = problem.high - problem.low
    x0 = problem.start.copy()
    state = load_state(out, problem) if (resume and out is not None) else None
    if state is not None:
        x0 = np.clip(np.array(state["x"], float), problem.low, problem.high)
        problem.photons = state.get("photons")
        log.info("resuming from the last accepted point (objective %.6g)", state["objective"])
    best: dict[str, Any] = {"F": math.inf, "x": x0.copy()}
    bar = tqdm(total=None, desc="fit", unit="eval", disable=not progress, leave=False)

    def phys(u: np.ndarray) -> np.ndarray:
        return problem.low + np.clip(u, 0.0, 1.0) * span

    def fun_x(x: np.ndarray) -> np.ndarray:
        return problem.residuals(x)

    def accept(x: np.ndarray, r: np.ndarray) -> None:
        F = float(r @ r)
        bar.update(1)
        if F < best["F"]:
            best.update(F=F, x=x.copy())
            bar.set_postfix(objective=f"{F:.5g}", walks=problem.walks)
            if out is not None:
                _write_json_atomic(out / STATE_NAME, {
                    "schema": STATE_SCHEMA, "identity": problem.identity(), "x": x.tolist(),
                    "names": [p.name for p in problem.free], "objective": F, "photons": problem.photons,
                    "evaluations": problem.evaluations})

    def fun_u(u: np.ndarray) -> np.ndarray:
        x = phys(u)
        r = fun_x(x)
        accept(x, r)
        return r

    def jac_u(u: np.ndarray) -> np.ndarray:
        x = phys(u)
        J = _jacobian(problem, x, fun_x(x), fun_x)
        bar.update(1)
        return J * span[None, :]

    r_start = fun_x(problem.start)
    F_start = float(r_start @ r_start)
    starts_u = [(x0 - problem.low) / span]
    if starts > 1 and state is None:
        from scipy.stats import qmc

        starts_u += list(qmc.LatinHypercube(d=x0.size, seed=int(problem.seed or 0)).random(starts - 1))
    results = []
    try:
        for su in starts_u:
            results.append(least_squares(fun_u, np.clip(su, 0.0, 1.0), jac=jac_u, bounds=(0.0, 1.0), method="trf",
                                         x_scale=1.0, max_nfev=max_evaluations, ftol=1e-8, xtol=1e-8, gtol=1e-10))
    finally:
        bar.close()
    x_best = best["x"]
    r_best = fun_x(x_best)
    J = _jacobian(problem, x_best, r_best, fun_x)
    pinv = np.linalg.pinv(J)

    # uncertainty: data noise and Monte Carlo noise propagated through the whole objective
    rng = np.random.default_rng(20260101 + int(problem.seed or 0))
    meas = problem.measured
    dp_data = []
    for _ in range(noise_draws):
        table = meas.table.copy()
        table["beta"] = table["beta"] + rng.standard_normal(len(table)) * table["u_beta"]
        noisy = make_dataset(table, meas.meta)
        dp_data.append(-pinv @ (problem.residuals(x_best, measured=noisy) - r_best))
    beta_shape = problem._table(problem.config_at(x_best)).R.shape[:2]
    dp_mc = [-pinv @ (problem.residuals(x_best, mc_noise=rng.standard_normal(beta_shape)) - r_best)
             for _ in range(noise_draws)]
    cov_data = np.atleast_2d(np.cov(np.array(dp_data).T, bias=True))
    cov_mc = np.atleast_2d(np.cov(np.array(dp_mc).T, bias=True))
    cov = cov_data + cov_mc
    u = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(u, u)
    corr[~np.isfinite(corr)] = 0.0
    notes = _identifiability(problem, J, u)
    for note in notes:
        log.warning("%s", note)
    info = {
        "optimiser": "scipy.optimize.least_squares (trf, bounds scaled to [0, 1])",
        "starts": len(starts_u), "status": [int(r.status) for r in results],
        "message": results[-1].message if results else "", "evaluations": problem.evaluations,
        "walks": problem.walks, "walk_seconds": problem.walk_seconds, "seconds": time.perf_counter() - t0,
        "photons": problem.photons, "resumed": state is not None,
        "singular_values": np.linalg.svd(J * span[None, :], compute_uv=False).tolist(),
    }
    if out is not None:
        _write_json_atomic(out / STATE_NAME, {
            "schema": STATE_SCHEMA, "identity": problem.identity(), "x": x_best.tolist(),
            "names": [p.name for p in problem.free], "objective": float(r_best @ r_best),
            "photons": problem.photons, "evaluations": problem.evaluations, "done": True})
    return FitResult(x=x_best, start=problem.start.copy(), objective=float(r_best @ r_best), objective_start=F_start,
                     u=u, u_data=np.sqrt(np.maximum(np.diag(cov_data), 0.0)),
                     u_mc=np.sqrt(np.maximum(np.diag(cov_mc), 0.0)), correlation=corr, warnings=notes, info=info)


def _identifiability(problem: FitProblem, J: np.ndarray, u: np.ndarray) -> list[str]:
    span = problem.high - problem.low
    notes = []
    _, s, vt = np.linalg.svd(J * span[None, :], full_matrices=False)
    names = [p.name for p in problem.free]
    flagged: set[str] = set()
    for k in range(s.size):
        if s[0] == 0 or s[k] < _FLAT * s[0]:
            v = vt[k] / np.max(np.abs(vt[k]))
            terms = " ".join(f"{c:+.2f}*{n}" for c, n in zip(v, names) if abs(c) > 0.2)
            notes.append(f"not identifiable: the objective is flat along {terms} (scaled singular value "
                         f"{s[k] / s[0] if s[0] else 0:.1e} of the largest)")
            flagged.update(n for c, n in zip(v, names) if abs(c) > 0.2)
    for name, uu, sp in zip(names, u, span):
        if name not in flagged and not uu <= 0.5 * sp:
            notes.append(f"not identifiable: {name} has an uncertainty ({uu:.3g}) above half its bound range "
                         f"({sp:.3g})")
    return notes


# ------------------------------------------------------------------------------------------
# outputs


def _summary(comparison) -> dict:
    name = next(iter(comparison.frames))
    out = {"nrmse": float(comparison.overall[name].nrmse)}
    if comparison.colour is not None:
        c = comparison.colour.simulated[name]
        out.update(dh=float(c.dh), ds=float(c.ds), h=float(c.colour.h), s=float(c.colour.s))
    return out


def write_outputs(problem: FitProblem, result: FitResult, out: Path) -> dict:
    """fitted.toml, initial/ and fitted/ datasets, report/ and fit.json in ``out``; returns fit.json."""
    from compare.comparison import compare_datasets
    from compare.report import write_report
    from gonio.data.dataset import write_dataset
    from simulate.montecarlo.accuracy import REL_ERR_DEFINITION, relative_error
    from simulate.provenance import jsonable, software_versions

    prov = {"command": GENERATOR, "config": problem.config.provenance(), "seed": problem.seed,
            "versions": software_versions()}
    b0, u0 = problem.model(result.start)
    b1, u1 = problem.model(result.x)
    rel_err = {"start": relative_error(b0, u0), "fitted": relative_error(b1, u1), "definition": REL_ERR_DEFINITION}
    initial = problem.dataset(b0, u0, "initial", {**prov, "rel_err": rel_err["start"],
                                                  "rel_err_definition": REL_ERR_DEFINITION})
    fitted = problem.dataset(b1, u1, "fitted", {**prov, "rel_err": rel_err["fitted"],
                                                "rel_err_definition": REL_ERR_DEFINITION,
                                                "fitted": {p.name: float(v) for p, v in zip(problem.free, result.x)}})
    write_dataset(initial, out / "initial")
    write_dataset(fitted, out / "fitted")
    lines = [f"{problem.config.name} fitted by `simulate fit` ({problem.method} model) to {problem.measured.source}",
             "free parameters (value +- standard uncertainty):"]
    lines += [f"  {p.name} = {v:.6g} +- {uu:.2g}" for p, v, uu in zip(problem.free, result.x, result.u)]
    (out / "fitted.toml").write_text(problem.fitted_toml(result.x, "\n".join(lines)), encoding="utf-8")
    comparison = compare_datasets(problem.measured, [initial, fitted])
    write_report(comparison, out / "report", force=True)
    c0 = _summary(problem.compare(initial))
    c1 = _summary(problem.compare(fitted))
    doc = {
        "generator": GENERATOR, "method": problem.method, "config": problem.config.name,
        "measured": str(problem.measured.source),
        "objective": {"definition": "NRMSE^2 + w_c (dh^2 + ds^2)", "colour_weight": problem.colour_weight,
                      "start": result.objective_start, "fitted": result.objective},
        "start": c0, "fitted": c1, "rel_err": rel_err,
        "parameters": [{"name": p.name, "kind": p.kind, "low": p.low, "high": p.high, "start": p.start,
                        "value": float(v), "u": float(uu), "u_data": float(ud), "u_mc": float(um)}
                       for p, v, uu, ud, um in zip(problem.free, result.x, result.u, result.u_data, result.u_mc)],
        "correlation": result.correlation.tolist(), "warnings": result.warnings, "info": result.info,
    }
    doc = jsonable(doc)
    _write_json_atomic(out / "fit.json", doc)
    return doc
