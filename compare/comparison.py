"""One comparison of simulated datasets against a measured dataset, and its metrics.

:func:`compare_datasets` runs the whole chain for any number of simulations:

0. the bands (:mod:`compare.bands`): wavelengths, or the channels of an RGB measurement, every
   simulation converted to them first (a spectral one through CIE XYZ, as in the colour match);
1. the shared wavelength grid (:func:`compare.align.shared_wavelengths`; the shared channels);
2. the measured normal/normal value and, per simulation, its own and the factor
   ``k(lambda)`` (:mod:`compare.normalise`);
3. per simulation, the values at the measured geometries (:func:`compare.align.align`),
   normalised: ``beta_sim = k * C``, ``u_sim = k * u_C``;
4. curve errors per incidence angle and overall (:mod:`compare.metrics`);
5. the colour match at the geometry closest to normal/normal (:mod:`compare.colourmatch`).

:meth:`Comparison.metrics` gives the ``metrics.json`` document (the contract of docs/architecture.md /
the issue)::

    {"normalisation": {"method": str,
                       "factor": {name: {"per_wavelength": {"390": k, ...},
                                         "u_per_wavelength": {...}, "median": k_med,
                                         "luminance": k_Y}},
                       "normal_value": {"measured": {"how": "estimated"|"measured"|"mixed",
                                                     "per_wavelength": {...},
                                                     "u_per_wavelength": {...}},
                                        name: {same keys (the simulation's C(0,0))}},
                       "level": {name: {"k", "ratio", "k_min", "k_max", "spread", "cv", "judged"}}},
     "curves": {name: {"0": {"rmse", "nrmse", "max_abs", "max_abs_at"}, "30": {...}, ...}},
     "overall": {name: {"rmse", "nrmse"}},
     "colour": {"geometry": {"theta_i", "phi_i", "theta_o", "phi_o", "s"},
                "measured": {"h", "s", "v", "blue_red", "green_red"},
                name: {"h", "s", "v", "blue_red", "green_red", "dh", "ds", "dv"}},
     "shape": {"measured" | name: {"opposition" | "mirror":
                                   {"per_incidence": {"40": {"value": {"550": r, ...}, "u": {...},
                                                            "n_points": [num, den]}}}
                                   or {"reason": str}}}}

``shape`` holds each dataset's own opposition and mirror-to-neighbours ratios
(:mod:`compare.ratios`; the normalisation cancels in them), or why the dataset lacks the
points they need.

Names are the datasets' ``name`` (``meta.sample.name`` or the directory name), made unique with a
`` (2)``, `` (3)`` suffix when they collide with each other or with the reserved keys
``measured`` and ``geometry``. Non-finite numbers are written as ``null``.

An RGB comparison writes ``per_channel`` / ``u_per_channel`` (keys ``R``, ``G``, ``B``, ``Y``)
in place of ``per_wavelength``, ``max_abs_at.channel`` in place of ``wavelength_nm``, and
``"bands": {"kind": "channel", "channels", "colour_space", "conversions": {name: how it was
converted}}``. A relative measurement adds ``"relative": true`` and has ``v`` and ``dv`` null
(absolute colour refused); a photometric (Y-only) one has an empty ``colour`` (no colour
statement). ``"notes"`` (sentences for a reader) is present when there is something to note. A
spectral comparison of absolute data has exactly the five keys above.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from gonio.data import Dataset

from .align import align, shared_wavelengths
from .bands import Bands, colour_resampling, prepare
from .colourmatch import ColourMatch, colour_match, colour_refusal
from .errors import CompareError
from .metrics import CurveError, curve_errors
from .normalise import (
    DEFAULT_WINDOW_DEG,
    METHOD_TEXT,
    Normalisation,
    NormalValue,
    estimate_normal_value,
    normalisation_factor,
)
from .ratios import shape_document

__all__ = ["DYNAMIC_RANGE_MAX", "MEASURED_BETA_MAX", "Comparison", "Level", "check_values",
           "compare_datasets", "incomplete_datasets", "same_dataset",
           "unique_names"]

log = logging.getLogger(__name__)

RESERVED_NAMES = ("measured", "geometry")


def unique_names(names: Iterable[str], reserved: Iterable[str] = RESERVED_NAMES) -> list[str]:
    """Names made unique by a `` (2)``, `` (3)``... suffix, avoiding ``reserved``.

    Parameters
    ----------
    names : iterable of str
        The names, in order.
    reserved : iterable of str, default RESERVED_NAMES
        Names no result may take.

    Returns
    -------
    list of str
        The names in the same order, each unique and none reserved.

    Examples
    --------
    >>> unique_names(["fiber", "fiber", "measured", "classic"])
    ['fiber', 'fiber (2)', 'measured (2)', 'classic']
    """
    taken = set(reserved)
    out = []
    for name in names:
        candidate, k = name, 1
        while candidate in taken:
            k += 1
            candidate = f"{name} ({k})"
        taken.add(candidate)
        out.append(candidate)
    return out


@dataclass(frozen=True)
class Level:
    """The absolute level of one simulation against the measurement.

    The per-wavelength normalisation hides it (docs/notes/fit-trust.md "The level").

    ``k`` is the luminance-weighted factor ``k_Y`` at the colour geometry (:mod:`compare.colourmatch`; the
    median ``k`` of a photometric comparison): the measurement is ``k`` times the model there. ``ratio`` =
    ``max(k, 1/k)`` is how many times brighter or darker the model is (1 at the measured level; ``compare
    check --max-level-ratio``). ``spread`` = ``max k / min k`` over the wavelengths (channels) and ``cv`` their
    coefficient of variation: a spread > 1 is a colour the normalisation took out at the normal. ``judged`` is
    False for a relative measurement (raw units: no level to judge).
    """

    k: float
    ratio: float
    k_min: float
    k_max: float
    spread: float
    cv: float
    judged: bool

    def as_dict(self) -> dict:
        """The level as ``metrics.json`` holds it (non-finite figures as None)."""
        def num(x):
            return float(x) if math.isfinite(float(x)) else None
        return {"k": num(self.k), "ratio": num(self.ratio), "k_min": num(self.k_min), "k_max": num(self.k_max),
                "spread": num(self.spread), "cv": num(self.cv), "judged": self.judged}

    def words(self, name: str, nrmse: float, max_ratio: float, max_nrmse: float) -> str:
        """One sentence on the level of ``name``: matched in shape but not in level, or at the level.

        Parameters
        ----------
        name : str
            The simulation's name.
        nrmse : float
            Its overall curve error (NRMSE), to say whether the shape matches.
        max_ratio : float
            The largest level ratio judged at the level.
        max_nrmse : float
            The largest NRMSE judged a match in shape.

        Returns
        -------
        str
            The sentence.
        """
        if not self.judged:
            return (f"'{name}': the measurement is relative (raw units), so its level is not judged; only shapes "
                    "and colour are compared")
        if not math.isfinite(self.ratio):
            return f"'{name}': its level could not be computed"
        how = "brighter" if self.k < 1 else "darker"
        spread = f"k from {self.k_min:.3g} to {self.k_max:.3g} over the bands, spread {self.spread:.2f}"
        if self.ratio <= max_ratio:
            return (f"'{name}' is at the measured level: within a factor {self.ratio:.2f} (limit {max_ratio:g}) at "
                    f"the colour geometry (k_Y {self.k:.3g}; {spread})")
        level = f"{self.ratio:.2f} times {how} than the measurement at the colour geometry (k_Y {self.k:.3g}; {spread})"
        shape = nrmse <= max_nrmse
        return (f"'{name}' {'matches in shape but not in level' if shape else 'is off in level as well'}: it is "
                f"{level}; the per-wavelength normalisation at the normal hides this (level ratio above "
                f"{max_ratio:g})")


@dataclass(frozen=True)
class Comparison:
    """Simulations compared with a measurement: what `fabric_optics.compare` returns (`compare_datasets`).

    Judge it with `fabric_optics.check`; write it as a report with `fabric_optics.write_report`.

    Attributes
    ----------
    measured : Dataset
        The measurement, as given.
    simulated : dict of str to Dataset
        The simulations by name, as given.
    wavelength_nm : numpy.ndarray
        The wavelengths compared (band codes for an RGB measurement: name them with `bands.label`).
    window_deg : float
        Largest |s| of the normal-incidence points of the measurement's normal value.
    illuminant : str
        Illuminant of the colour match.
    measured_normal : NormalValue
        The measurement at the normal direction, with its uncertainty.
    normalisations : dict of str to Normalisation
        Per simulation the factor k(lambda) that scales it to the measurement at the normal.
    frames : dict of str to pandas.DataFrame
        Per simulation the aligned table: measured and normalised simulated values per geometry and band.
    curves : dict of str to dict of str to CurveError
        Per simulation and incidence: `rmse`, `nrmse`, `max_abs` and where.
    overall : dict of str to CurveError
        Per simulation the errors over every geometry and band: `.overall[name].nrmse`.
    colour : ColourMatch or None
        The HSV colour match near the normal direction (`.simulated[name].dh`, `.ds`); None when
        the measurement has no colour (photometric, Y only).
    bands : Bands
        How the bands were matched (spectral, or the channels of an RGB measurement).
    measured_view, simulated_views : Dataset, dict of str to Dataset
        What was compared: the datasets themselves for a spectral comparison, their channel views
        (`compare.bands`) for an RGB one.
    colour_note : str
        Why no colour is stated for a spectral comparison, or "".
    """

    measured: Dataset
    simulated: dict[str, Dataset]
    wavelength_nm: np.ndarray
    window_deg: float
    illuminant: str
    measured_normal: NormalValue
    normalisations: dict[str, Normalisation]
    frames: dict[str, pd.DataFrame]
    curves: dict[str, dict[str, CurveError]]
    overall: dict[str, CurveError]
    colour: ColourMatch | None
    bands: Bands = field(default_factory=Bands)
    measured_view: Dataset | None = None
    simulated_views: dict[str, Dataset] = field(default_factory=dict)
    #: why no colour is stated for a spectral comparison (:func:`compare.colourmatch.colour_refusal`), or ""
    colour_note: str = ""

    def colour_matched(self) -> ColourMatch:
        """The colour match, for what draws or states it (:class:`CompareError` when there is none)."""
        if self.colour is None:
            raise CompareError("no colour was compared" + (f": {self.colour_note}" if self.colour_note else ""))
        return self.colour

    @property
    def relative(self) -> bool:
        """True when the measurement is relative (raw units): no absolute colour statement (V)."""
        return self.measured.relative

    def notes(self) -> list[str]:
        """What a reader must know about how the data were compared.

        Shown in the report and by ``compare check``.
        """
        out = list(self.bands.conversions.values())
        if not self.bands.is_rgb:
            out += self.interpolation_notes()
        if self.bands.is_rgb and not self.bands.has_colour:
            chans = ", ".join(self.bands.channels or ())
            out.append("the measurement is photometric (channel Y): the comparison is on Y "
                       "only and makes no colour statement (no H, S, V)"
                       if chans == "Y" else
                       f"the compared channels ({chans}) do not include all of R, G and B: no "
                       "colour statement is made (no H, S, V)")
        if self.colour_note:
            out.append(f"no colour statement (no H, S, V): {self.colour_note}")
        if not self.bands.is_rgb and colour_resampling(self.wavelength_nm)[1] is not None:
            out.append("the compared wavelengths are not a 1, 5, 10 or 20 nm grid (ASTM E308): CIE Y (the "
                       "luminance curves, k_Y) and any colour are integrated from the spectrum interpolated "
                       "linearly to 5 nm between them and held at its end values beyond them")
        if self.relative:
            out.append(f"measured dataset '{self.measured.name}' is relative (\"relative\": true, "
                       "raw detector units): it is normalised like any other (only shapes are "
                       "needed), but no absolute colour statement is made: V and dv are refused "
                       "(H, S and the channel ratios do not depend on the scale and are given)")
        return out

    def simulated_wavelengths_used(self, name: str) -> int:
        """How many of the compared wavelengths the simulation ``name`` holds itself.

        The others were linearly interpolated in wavelength (:mod:`compare.align`).

        Parameters
        ----------
        name : str
            The simulation's name.

        Returns
        -------
        int
            The count of compared wavelengths found on the simulation's own grid.
        """
        wl = self.simulated[name].wavelengths_nm
        grid = self.wavelength_nm
        if wl.size == 0:
            return 0
        return int(np.sum(np.min(np.abs(grid[:, None] - wl[None, :]), axis=1) < 1e-6))

    def interpolation_notes(self) -> list[str]:
        """One sentence per simulation whose wavelengths are not all the compared ones."""
        grid = self.wavelength_nm
        out = []
        for name, ds in self.simulated.items():
            own = self.simulated_wavelengths_used(name)
            if own < grid.size:
                wl = ds.wavelengths_nm
                out.append(
                    f"'{name}' holds {wl.size} wavelengths ({wl[0]:g}..{wl[-1]:g} nm), {own} of "
                    f"the {grid.size} compared (measured) ones: its values at the other "
                    f"{grid.size - own} were linearly interpolated in wavelength between the "
                    "bracketing simulated wavelengths (gonio.data interpolate) before "
                    "normalising, comparing and taking colours; curves and colours at those "
                    "wavelengths are interpolated model values, not simulated ones")
        return out

    def view(self, name: str) -> Dataset:
        """The simulation ``name`` as compared (its channel view in an RGB comparison).

        Parameters
        ----------
        name : str
            The simulation's name.

        Returns
        -------
        Dataset
            The channel view, or the simulation itself.
        """
        return self.simulated_views.get(name, self.simulated[name])

    @property
    def measured_compared(self) -> Dataset:
        """The measurement as compared (its channel view in an RGB comparison)."""
        return self.measured_view if self.measured_view is not None else self.measured

    def nrmse_with_factor_shifted(self, name: str) -> tuple[float, float]:
        """Overall NRMSE of ``name`` with every ``k(lambda)`` moved to ``k - u_k`` and to ``k + u_k``.

        How far the normalisation's own uncertainty (fully correlated across the curve, so it does
        not average out) can move the curve error. Not in ``metrics.json``,
        whose NRMSE uses ``k`` itself.

        Parameters
        ----------
        name : str
            The simulation's name.

        Returns
        -------
        tuple of float
            The overall NRMSE with ``k - u_k`` and with ``k + u_k``.
        """
        frame = self.frames[name]
        norm = self.normalisations[name]
        wl = frame["wavelength_nm"].to_numpy()
        k = norm.factor_at(wl)
        u = norm.u_factor_at(wl)
        out = []
        for sign in (-1.0, 1.0):
            shifted = frame.assign(beta_sim=(k + sign * u) * frame["beta_sim_raw"].to_numpy())
            out.append(curve_errors(shifted)[1].nrmse)
        return out[0], out[1]

    def level(self, name: str) -> Level:
        """The absolute level of simulation ``name`` (`Level`: `k`, `ratio`, `spread`, `judged`).

        Parameters
        ----------
        name : str
            The simulation's name.

        Returns
        -------
        Level
            The level figures of the simulation.
        """
        k_all = np.asarray(self.normalisations[name].factor, float)
        if self.colour is not None:
            k = float(self.colour.simulated[name].scale)
        else:
            k = float(np.median(k_all))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = max(k, 1.0 / k) if k > 0 and math.isfinite(k) else math.nan
            spread = float(k_all.max() / k_all.min()) if k_all.size and k_all.min() > 0 else math.nan
            cv = float(np.std(k_all) / np.mean(k_all)) if k_all.size else math.nan
        return Level(k=k, ratio=ratio, k_min=float(k_all.min()), k_max=float(k_all.max()), spread=spread, cv=cv,
                     judged=not self.relative)

    def metrics(self) -> dict:
        """The ``metrics.json`` document (see the module docstring)."""
        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        bands = self.bands
        per = "per_channel" if bands.is_rgb else "per_wavelength"

        def per_wl(wl, values):
            return {bands.key(w): num(v) for w, v in zip(wl, values, strict=True)}

        def normal(nv: NormalValue):
            return {"how": nv.how, per: per_wl(nv.wavelength_nm, nv.value),
                    "u_" + per: per_wl(nv.wavelength_nm, nv.u)}

        def where(at: dict) -> dict:
            out = {k: (num(v) if v is not None else None) for k, v in at.items()}
            if bands.is_rgb:
                band = out.pop("wavelength_nm")
                out["channel"] = bands.label(band) if band is not None else None
            return out

        factor = {}
        normal_value = {"measured": normal(self.measured_normal)}
        for name, norm in self.normalisations.items():
            factor[name] = {per: per_wl(norm.wavelength_nm, norm.factor),
                            "u_" + per: per_wl(norm.wavelength_nm, norm.u_factor),
                            "median": num(np.median(norm.factor)),
                            "luminance": (num(self.colour.simulated[name].scale)
                                          if self.colour is not None else None)}
            normal_value[name] = normal(norm.simulated)
        curves = {name: {angle: {"rmse": num(e.rmse), "nrmse": num(e.nrmse),
                                 "max_abs": num(e.max_abs),
                                 "max_abs_at": where(e.max_abs_at)}
                         for angle, e in per_angle.items()}
                  for name, per_angle in self.curves.items()}
        overall = {name: {"rmse": num(e.rmse), "nrmse": num(e.nrmse)}
                   for name, e in self.overall.items()}
        relative = self.relative

        def summary(c):
            return {"h": num(c.h), "s": num(c.s), "v": None if relative else num(c.v),
                    "blue_red": num(c.blue_red), "green_red": num(c.green_red)}

        colour: dict = {}
        if self.colour is not None:
            colour = {"geometry": {k: (num(v) if v is not None else None)
                                   for k, v in self.colour.geometry.items()},
                      "measured": summary(self.colour.measured)}
            for name, sc in self.colour.simulated.items():
                colour[name] = {**summary(sc.colour), "dh": num(sc.dh), "ds": num(sc.ds),
                                "dv": None if relative else num(sc.dv)}
        method = METHOD_TEXT.format(window=self.window_deg)
        if bands.is_rgb:
            method = method.replace("per wavelength", "per channel").replace("k(lambda)", "k(c)")
        level = {name: self.level(name).as_dict() for name in self.normalisations}
        shape = {"measured": shape_document(self.measured_compared.table, bands.key)}
        shape.update({name: shape_document(self.view(name).table, bands.key) for name in self.simulated})
        document: dict = {"normalisation": {"method": method, "factor": factor,
                                            "normal_value": normal_value, "level": level},
                          "curves": curves, "overall": overall, "colour": colour, "shape": shape}
        if self.colour_note:
            document["colour_note"] = f"no colour statement (no H, S, V): {self.colour_note}"
        if bands.is_rgb:
            document["bands"] = {"kind": bands.noun, "channels": list(bands.channels or ()),
                                 "colour_space": bands.colour_space,
                                 "conversions": dict(bands.conversions)}
        if relative:
            document["relative"] = True
        if self.notes():
            document["notes"] = self.notes()
        return document


#: Largest ``|beta|`` of an absolute (not ``"relative"``) measurement: ten times the radiance
#: coefficient of a mirror seen through a milliradian aperture (~1e6, gonio.data.dataset.BETA_MAX's
#: note); anything larger is raw detector units (mark the dataset ``"relative": true``) or an error.
MEASURED_BETA_MAX = 1e7
#: Largest ratio of one ``|beta|`` to the dataset's median ``|beta|`` (nine decades: a specular
#: peak of 1e6 over a diffuse floor of 1e-3 still passes); a larger spike is a corrupt value,
#: which would otherwise dominate every curve error instead of being named.
DYNAMIC_RANGE_MAX = 1e9


def check_values(ds: Dataset, role: str) -> None:
    """Refuse a dataset whose ``beta`` is not finite or absurd.

    Raises :class:`CompareError`: one line naming the dataset, the field, the row's geometry and
    what to do.

    Parameters
    ----------
    ds : Dataset
        The dataset to check.
    role : str
        ``"measured"`` or ``"simulated"``: the measured level is also checked for plausibility.

    Raises
    ------
    CompareError
        When a ``beta`` is not finite, a measured absolute ``beta`` is implausibly large, or one value
        exceeds the dataset's median many times over.
    """
    table = ds.table
    beta = table["beta"].to_numpy(dtype=float)
    band = ds.band_column

    def where(i: int) -> str:
        row = table.iloc[i]
        b = row[band]
        return (f"theta_i={row['theta_i']:g}, phi_i={row['phi_i']:g}, theta_o={row['theta_o']:g}, "
                f"phi_o={row['phi_o']:g}, " + (f"channel {b}" if ds.is_rgb else f"{float(b):g} nm"))

    head = f"{role} dataset '{ds.name}' ({ds.source}): field beta"
    bad = ~np.isfinite(beta)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise CompareError(f"{head} is {beta[i]} at {where(i)}; every value must be a finite "
                           "number (leave out a point whose value is unknown)")
    size = np.abs(beta)
    if role == "measured" and not ds.relative and size.max() > MEASURED_BETA_MAX:
        i = int(np.argmax(size))
        raise CompareError(f"{head} is {beta[i]:g} at {where(i)}, not a plausible radiance "
                           f"coefficient (|beta| <= {MEASURED_BETA_MAX:g}); raw detector units "
                           "need \"relative\": true in meta.json, otherwise correct the value")
    nonzero = size[size > 0]
    if nonzero.size:
        typical = float(np.median(nonzero))
        if size.max() > DYNAMIC_RANGE_MAX * typical:
            i = int(np.argmax(size))
            raise CompareError(f"{head} is {beta[i]:g} at {where(i)}, more than "
                               f"{DYNAMIC_RANGE_MAX:g} times the dataset's median |beta| "
                               f"({typical:.3g}): a corrupt value, not a reflectance; correct or "
                               "remove that row")


def same_dataset(a: Dataset, b: Dataset) -> str:
    """Why ``a`` and ``b`` are the same data (same directory or same content), or ``""``.

    Parameters
    ----------
    a, b : Dataset
        The two datasets.

    Returns
    -------
    str
        ``"the same directory"``, ``"the same radiance.csv content"`` or ``""``.
    """
    if a.path is not None and b.path is not None:
        try:
            if Path(a.path).resolve() == Path(b.path).resolve():
                return "the same directory"
        except OSError:
            pass
    if a.content_sha256() == b.content_sha256():
        return "the same radiance.csv content"
    return ""


def incomplete_datasets(measured: Dataset, simulated: Iterable[Dataset]) -> list[str]:
    """One line per dataset whose meta says it is incomplete (``"complete": false``).

    Parameters
    ----------
    measured : Dataset
        The measurement.
    simulated : iterable of Dataset
        The simulations.

    Returns
    -------
    list of str
        One line per incomplete dataset, naming its role, name and source; empty when all are complete.
    """
    out = []
    for role, ds in [("measured", measured)] + [("simulated", s) for s in simulated]:
        if not ds.complete:
            out.append(f"{role} dataset '{ds.name}' ({ds.source}) is incomplete: "
                       f"{ds.completeness()}")
    return out


def compare_datasets(measured: Dataset, simulated: Sequence[Dataset], *,
                     window_deg: float = DEFAULT_WINDOW_DEG,
                     illuminant: str = "D65") -> Comparison:
    """Normalise each simulation at the normal direction and compare it with ``measured``.

    Parameters
    ----------
    measured : gonio.data.Dataset
        The reference (normally ``kind == "measured"``).
    simulated : sequence of gonio.data.Dataset
        One or more simulations (e.g. the fiber model and the classic model).
    window_deg : float
        Half-width in ``s`` of the normal/normal estimate (:mod:`compare.normalise`).
    illuminant : str
        Illuminant of the colour match.

    Raises
    ------
    CompareError
        When the datasets cannot be compared (see :mod:`compare.normalise`, :mod:`compare.align`).
    """
    if not simulated:
        raise CompareError("no simulated dataset to compare with the measurement")
    import colour

    if illuminant not in colour.SDS_ILLUMINANTS:
        raise CompareError(f"unknown illuminant {illuminant!r}; use a key of "
                           "colour.SDS_ILLUMINANTS such as 'D65', 'D50' or 'A'")
    if measured.kind != "measured":
        log.warning("the reference dataset '%s' is of kind %r, not 'measured'", measured.name,
                    measured.kind)
    for sim in simulated:
        same = same_dataset(measured, sim)
        if same:
            log.warning("comparing dataset '%s' (%s) with itself (%s): every figure will agree "
                        "trivially; pass the simulation's directory as SIM_DIR", sim.name,
                        sim.source, same)
    check_values(measured, "measured")
    for sim in simulated:
        check_values(sim, "simulated")
    names = unique_names(ds.name for ds in simulated)
    measured_view, views, bands = prepare(measured, simulated, names, illuminant=illuminant)
    grid = bands.codes() if bands.is_rgb else shared_wavelengths(measured, simulated)
    measured_normal = estimate_normal_value(measured_view, window_deg, bands.label)
    normalisations: dict[str, Normalisation] = {}
    frames: dict[str, pd.DataFrame] = {}
    curves: dict[str, dict[str, CurveError]] = {}
    overall: dict[str, CurveError] = {}
    for name, sim in zip(names, views, strict=True):
        # like for like: a measurement without the normal/normal point gets a simulation's estimated
        # from the same neighbours (compare.normalise.estimate_normal_value, use_exact)
        norm = normalisation_factor(measured_normal,
                                    estimate_normal_value(sim, window_deg, bands.label,
                                                          use_exact=measured_normal.how == "measured"), grid)
        frame = align(measured_view, sim, grid)
        k = norm.factor_at(frame["wavelength_nm"].to_numpy())
        frame["beta_sim"] = k * frame["beta_sim_raw"].to_numpy()
        frame["u_sim"] = k * frame["u_sim_raw"].to_numpy()
        normalisations[name] = norm
        frames[name] = frame
        curves[name], overall[name] = curve_errors(frame)
        log.info("'%s': overall RMSE %.4g, NRMSE %.4g", name, overall[name].rmse,
                 overall[name].nrmse)
    colour_result: ColourMatch | None = None
    colour_note = "" if bands.is_rgb else (colour_refusal(grid, illuminant) or "")
    if colour_note:
        log.warning("no colour (H, S, V) is stated: %s; the curves and their errors are compared", colour_note)
    if bands.has_colour and not colour_note:
        colour_result = colour_match(frames, {n: (normalisations[n].measured_value,
                                           normalisations[n].simulated_value) for n in names},
                              illuminant=illuminant, bands=bands)
    return Comparison(measured=measured, simulated=dict(zip(names, simulated, strict=True)),
                      wavelength_nm=grid, window_deg=window_deg, illuminant=illuminant,
                      measured_normal=measured_normal, normalisations=normalisations,
                      frames=frames, curves=curves, overall=overall, colour=colour_result,
                      bands=bands, measured_view=measured_view,
                      simulated_views=dict(zip(names, views, strict=True)), colour_note=colour_note)
