"""Report sections that say what was measured and judge a simulated seed sample.

``measured_sample_section(dataset)``
    "What was measured", right under the title: the measured dataset's sample (its ``sample``
    meta) and, for an acquisition through the mock goniophotometer (``gonio demo``, which records
    the mock's virtual sample as ``sample.mock_sample``; or an instrument whose identity says
    ``MOCK``), plainly that the instrument is the mock and what it held: a real measurement
    file (its description, SHA-256 and source, e.g. the RGL green felt, CC0), the analytic
    red-cotton stand-in (*not* a measurement of a fabric), a Lambertian or a dataset. None for a
    dataset that says nothing of the kind (an imported file, a real instrument).
``seed_sample_section(dataset)``
    A simulated dataset of red cotton judged against the published colour of red cotton at the
    report's colour geometry (incidence 0, observation +10 deg in plane; linear sRGB, D65,
    CIE 1931 2 deg: :func:`gonio.data.colour.spectrum_colour`, the computation of the slow test
    ``test_red_cotton_fabric_colour_in_the_published_range``): each quantity in or out of its
    range (:data:`PUBLISHED_RED_COTTON`, docs/physics.md sections 6.4 and 8).

Both are :class:`compare.report.Section` s for :func:`compare.report.write_report`; ``compare
report`` adds the first by itself and the second with ``--seed-sample DIR``.
"""

from __future__ import annotations

import html
from dataclasses import dataclass

import numpy as np

from ..errors import CompareError
from .page import Section

__all__ = ["PUBLISHED_RED_COTTON", "SEED_GEOMETRY", "RangeCheck", "measured_sample_section",
           "published_colour_check", "seed_sample_section"]

#: Published colour of red cotton at the colour geometry: ``quantity: (low, high)`` (None: open),
#: docs/physics.md section 6.4 (H in turns, linear sRGB, D65).
PUBLISHED_RED_COTTON: dict[str, tuple[float | None, float | None]] = {
    "h": (0.97, 0.99), "s": (0.97, None), "blue_red": (0.05, 0.25), "green_red": (0.005, 0.03)}

#: The colour geometry of the published table: incidence 0, in-plane observation s = +10 deg.
SEED_GEOMETRY = (0.0, 10.0)

_LABELS = {"h": "H (turns)", "s": "S", "blue_red": "BLUE/RED", "green_red": "GREEN/RED"}


@dataclass(frozen=True)
class RangeCheck:
    """One quantity against its published range."""

    quantity: str
    value: float
    low: float | None
    high: float | None

    @property
    def ok(self) -> bool:
        """In range (NaN is not)."""
        return (bool(np.isfinite(self.value)) and (self.low is None or self.value >= self.low)
                and (self.high is None or self.value <= self.high))

    def range_text(self) -> str:
        """``0.97-0.99``, ``>= 0.97`` or ``<= X``."""
        if self.low is not None and self.high is not None:
            return f"{self.low:g}-{self.high:g}"
        return f">= {self.low:g}" if self.low is not None else f"<= {self.high:g}"

    def line(self) -> str:
        """``H (turns) 0.979 in range 0.97-0.99`` (for a terminal)."""
        verdict = "in range" if self.ok else "OUT OF RANGE"
        return f"{_LABELS[self.quantity]} {self.value:.4g} {verdict} {self.range_text()}"


def published_colour_check(dataset, ranges=None):
    """``(ColourSummary, [RangeCheck, ...])`` of ``dataset`` at :data:`SEED_GEOMETRY`.

    Raises :class:`CompareError` (naming the dataset) for an RGB dataset or one without the
    geometry.

    Parameters
    ----------
    dataset : Dataset
        A spectral dataset holding the in-plane spectrum at :data:`SEED_GEOMETRY`.
    ranges : dict, optional
        Quantity (``h``, ``s``, ``blue_red``, ``green_red``) -> ``(low, high)``, either None for no
        bound (default :data:`PUBLISHED_RED_COTTON`).

    Returns
    -------
    colour : ColourSummary
        The dataset's colour there.
    checks : list of RangeCheck
        One check per quantity of ``ranges``.

    Raises
    ------
    CompareError
        For an RGB dataset or one without the geometry.

    Examples
    --------
    >>> RangeCheck("h", 0.979, 0.97, 0.99).ok, RangeCheck("s", 0.95, 0.97, None).line()
    (True, 'S 0.95 OUT OF RANGE >= 0.97')
    """
    from gonio.data.colour import spectrum_colour

    ranges = PUBLISHED_RED_COTTON if ranges is None else ranges
    where = dataset.source or dataset.name
    if dataset.is_rgb:
        raise CompareError(f"--seed-sample {where}: an RGB dataset; the published colour is judged "
                           "from a spectrum (simulate fabric red-cotton --method summation)")
    theta_i, s = SEED_GEOMETRY
    rows = dataset.in_plane(theta_i=theta_i)
    rows = rows[np.abs(rows["s"].to_numpy() - s) < 1e-6].sort_values("wavelength_nm")
    if len(rows) < 3:
        raise CompareError(f"--seed-sample {where}: no spectrum at incidence {theta_i:g}, "
                           f"observation s = {s:+g} deg (simulate it at the red-cotton plan)")
    colour = spectrum_colour(rows["wavelength_nm"].to_numpy(), rows["beta"].to_numpy())
    checks = [RangeCheck(q, float(getattr(colour, q)), lo, hi) for q, (lo, hi) in ranges.items()]
    return colour, checks


def seed_sample_section(dataset) -> Section:
    """The seed sample's colour against :data:`PUBLISHED_RED_COTTON` (module docstring).

    Parameters
    ----------
    dataset : Dataset
        The simulated seed sample (:func:`published_colour_check`).

    Returns
    -------
    Section
        The section, at the end of the page.

    Raises
    ------
    CompareError
        For an RGB dataset or one without the geometry.
    """
    e = html.escape
    colour, checks = published_colour_check(dataset)
    rows = "".join(f"<tr><td class='l'>{e(_LABELS[c.quantity])}</td><td>{c.value:.4f}</td>"
                   f"<td>{e(c.range_text())}</td><td class='l'>"
                   f"{'in range' if c.ok else '<b>out of range</b>'}</td></tr>" for c in checks)
    verdict = ("every quantity in its published range" if all(c.ok for c in checks) else
               "out of range: " + ", ".join(_LABELS[c.quantity] for c in checks if not c.ok))
    model = dataset.meta.get("model") or {}
    body = (f"<h2>Seed sample: red cotton against its published colour</h2><p>The simulated "
            f"dataset '{e(dataset.name)}' ({e(str(model.get('generator', '')))} "
            f"{e(str(model.get('method', '')))}, config {e(str(model.get('config', '')))}) at "
            f"incidence {SEED_GEOMETRY[0]:g} deg, observation s = {SEED_GEOMETRY[1]:+g} deg in "
            "plane: its spectrum -> CIE XYZ (CIE 1931 2 deg, D65) -> linear sRGB -> HSV and the "
            "channel ratios, against the published measurement of red cotton (docs/physics.md "
            f"sections 6.4 and 8). Verdict: {e(verdict)}. (V {colour.v:.3f} is not judged: "
            "it depends on the absolute level.)</p><table><tr><th class='l'>quantity</th>"
            f"<th>simulated</th><th>published</th><th class='l'>verdict</th></tr>{rows}</table>")
    return Section("seed-sample", body, before=None)


def measured_sample_section(dataset) -> Section | None:
    """What the measured dataset is (module docstring), or None when it says nothing of it.

    Parameters
    ----------
    dataset : Dataset
        The measurement.

    Returns
    -------
    Section or None
        The section, under the title; None for a dataset not measured through the mock
        goniophotometer.
    """
    e = html.escape
    sample = dataset.meta.get("sample") or {}
    mock = sample.get("mock_sample") if isinstance(sample, dict) else None
    idn = str((dataset.meta.get("instrument") or {}).get("idn", ""))
    if not isinstance(mock, dict) and "MOCK" not in idn.upper():
        return None
    name = e(dataset.name)
    head = (f"<h2>What was measured</h2><p class='note'>The measurement '{name}' was acquired "
            "through the <b>mock goniophotometer</b> (gonio.mock: a simulated instrument on the "
            "real protocol endpoints, Modbus TCP and an ASCII photometer head, driven by the same "
            "driver as a real one; calibration, counts and noise simulated). ")
    if not isinstance(mock, dict):
        return Section("measured-sample", head + "Its virtual sample is not recorded in the "
                       "dataset (written before gonio demo recorded it).</p>", before="howto")
    model = str(mock.get("model", ""))
    if mock.get("name") == "red-cotton" or model.startswith("analytic"):
        what = ("Its sample is the mock's <b>analytic stand-in for red cotton</b> (an Oren-Nayar "
                "lobe with a red dye spectrum, a retro-reflection peak, an anisotropic Ward "
                "gloss lobe, a forward sheen and a backscatter lobe, gonio.mock.samples): <b>not a measurement of a real fabric</b>, so "
                "these model errors say how far the models are from that formula, not from a "
                "fabric.")
    elif model.startswith("RGL"):
        source = mock.get("source")
        what = (f"Its sample is a <b>real measurement</b>: the RGL .bsdf file "
                f"<code>{e(str(mock.get('path', '')))}</code> ('{e(str(mock.get('description', '')))}'"
                f", SHA-256 {e(str(mock.get('sha256', ''))[:16])}...), "
                + (f"from the {e(str(source))}. " if source else "of unrecorded source. ")
                + "The mock evaluates the file at every geometry it is asked (the full measured "
                "BRDF) and, being spectral while the file is RGB, answers each wavelength with the "
                "spectrum whose colour is the file's RGB there (the spectral primary decomposition "
                "of Mallett and Yuksel 2019, linear in the RGB, gonio.mock.upsample): the colours "
                "are the felt's, while the spectral shapes inside each channel are that "
                "decomposition's assumption, not measured.")
    elif model == "lambert":
        what = f"Its sample is an ideal diffuse reflector ({e(str(mock.get('name', '')))})."
    else:
        what = (f"Its sample is the dataset <code>{e(str(mock.get('path', '')))}</code> "
                "(interpolated by the mock).")
    return Section("measured-sample", head + what + "</p>", before="howto")
