"""Report sections: what was measured (the mock's sample, a real file's source), the
fitted parameters from `simulate fit`'s fit.json, the seed sample against red cotton's published
colour; and `compare report --fit / --seed-sample`."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from compare.errors import CompareError
from compare.report.fits import fits_section
from compare.report.samples import measured_sample_section, published_colour_check, seed_sample_section
from fabric_optics.cli.compare import main
from gonio.data import write_dataset

FELT_SHA = "3429e2bdbe2045dca11582479fa251866ffe056b909b47e3fbf1c3c776fcb72b"


def _red(wl):
    """An independent red: the mock's red-cotton dye curve written out (gonio.mock.samples)."""
    wl = np.asarray(wl, float)
    return (0.01 + 0.088 * np.exp(-0.5 * ((wl - 420.0) / 40.0) ** 2)
            + 0.91 / (1.0 + np.exp(-(wl - 594.7) / 7.1)))


def _seed(h, grey: float, name="seed red"):
    """A simulated spectrum at incidence 0, s = +10 (and -10): the red plus ``grey`` white."""
    table = h.in_plane_table(lambda ti, s, wl: _red(wl) + grey, incidence=(0.0,), s_grid=[-10.0, 10.0])
    return h.dataset(table, kind="simulated", name=name)


@pytest.mark.parametrize("grey,failing", [
    (0.02, set()),                          # H 0.988, S 0.978, B/R 0.091, G/R 0.022: all in range
    (0.05, {"s", "green_red"}),             # whiter: S 0.946, G/R 0.054 out; H, B/R still in
    (None, {"h", "s", "blue_red", "green_red"}),   # a flat grey: no red at all
])
def test_the_seed_check_says_which_quantities_leave_the_published_range(h, grey, failing):
    ds = (_seed(h, grey) if grey is not None else
          h.dataset(h.in_plane_table(lambda ti, s, wl: 0.5 + 0 * wl, incidence=(0.0,), s_grid=[10.0]),
                    kind="simulated", name="grey"))
    _, checks = published_colour_check(ds)
    assert {c.quantity for c in checks} == {"h", "s", "blue_red", "green_red"}
    assert {c.quantity for c in checks if not c.ok} == failing
    html = seed_sample_section(ds).html
    assert html.count("out of range</b>") == len(failing)


def test_the_seed_check_needs_the_colour_geometry(h):
    ds = h.dataset(h.in_plane_table(lambda ti, s, wl: _red(wl), incidence=(0.0,), s_grid=[20.0]),
                   kind="simulated", name="elsewhere")
    with pytest.raises(CompareError, match="no spectrum at incidence 0, observation s = \\+10"):
        published_colour_check(ds)


def _measured(h, sample: dict, idn: str = "KIAM,GPS-1,MOCK0001,2.3"):
    ds = h.dataset(h.in_plane_table(lambda ti, s, wl: 0.3 + 0 * wl, incidence=(0.0,), s_grid=[10.0]),
                   **{k: v for k, v in sample.items() if k != "name"}, name=sample["name"])
    ds.meta = {**ds.meta, "instrument": {"idn": idn}}
    return ds


def test_the_measured_sample_is_said_plainly(h):
    felt = _measured(h, {"name": "green acrylic felt", "mock_sample": {
        "name": "acrylic_felt_green_rgb", "model": "RGL .bsdf (Dupuy & Jakob 2018)",
        "path": "fixtures/real/acrylic_felt_green_rgb.bsdf", "description": "Green acrylic felt",
        "sha256": FELT_SHA, "source": "RGL material database, EPFL, licence CC0 1.0"}})
    text = measured_sample_section(felt).html
    assert "mock goniophotometer" in text and "real measurement" in text
    assert "acrylic_felt_green_rgb.bsdf" in text and FELT_SHA[:16] in text and "CC0" in text
    cotton = _measured(h, {"name": "red cotton", "mock_sample": {
        "name": "red-cotton", "model": "analytic Oren-Nayar + retro + Ward (gonio.mock.samples)"}})
    text = measured_sample_section(cotton).html
    assert "stand-in" in text and "not a measurement of a real fabric" in text
    old_demo = _measured(h, {"name": "red cotton"})
    assert "not recorded" in measured_sample_section(old_demo).html
    real_instrument = _measured(h, {"name": "felt"}, idn="ACME,G-2,SN42,1.0")
    assert measured_sample_section(real_instrument) is None


def _fit_dir(root: Path, method: str, params: list[tuple[str, float, float]]) -> Path:
    d = root / f"fit-{method}"
    d.mkdir()
    doc = {"generator": "simulate fit", "method": method, "config": "red-cotton",
           "start": {"nrmse": 1.43, "dh": -0.288, "ds": -0.055},
           "fitted": {"nrmse": 0.3301, "dh": -0.0136, "ds": -0.1357},
           "parameters": [{"name": n, "kind": "surface", "low": 0.02, "high": 0.5, "start": 0.35,
                           "value": v, "u": u, "u_data": u / 2, "u_mc": u / 3} for n, v, u in params],
           "warnings": ["at its lower bound: something <b>"], "info": {"evaluations": 59,
                                                                    "max_evaluations": 60, "walks": 1,
                                                                    "seconds": 79.1}}
    (d / "fit.json").write_text(json.dumps(doc))
    (d / "fitted.toml").write_text("name = 'x'\n")
    return d


def test_the_fit_section_lists_values_uncertainties_and_what_was_evaluated_at_them(h, tmp_path):
    fit = _fit_dir(tmp_path, "summation", [("surface.rms_slope", 0.2563558, 0.00071)])
    mc = _seed(h, 0.0, name="mc at the fit")
    mc.meta = {**mc.meta, "provenance": {"config": {"source": str(fit / "fitted.toml")}}}
    other = _seed(h, 0.0, name="unrelated")
    section = fits_section([fit], {"mc at the fit": mc, "unrelated": other})
    text = section.html
    assert "surface.rms_slope" in text and "<b>0.2564</b>" in text and "<td>0.00071</td>" in text
    assert "<td>0.00036</td>" in text and "[0.02, 0.5]" in text          # u_data = u/2, bounds
    assert "NRMSE 1.43" in text and "NRMSE 0.3301" in text and "59 evaluations" in text
    assert "something &lt;b&gt;" in text                                   # warnings, escaped
    assert "'mc at the fit' is evaluated at these fitted parameters" in text
    assert "'unrelated'" not in text
    with pytest.raises(CompareError, match="no fit.json there"):
        fits_section([tmp_path / "nothing"])


def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([str(a) for a in argv])
    return status, out.getvalue(), err.getvalue()


def test_compare_report_fit_and_seed_sample_options(h, tmp_path):
    fit = _fit_dir(tmp_path, "classic", [("surface.rms_slope", 0.264, 0.0013)])
    seed = write_dataset(_seed(h, 0.05, name="red cotton summation"), tmp_path / "seed")
    out = tmp_path / "report"
    status, stdout, stderr = _run(["report", h.FIXTURES / "measured_red", h.FIXTURES / "sim_grey",
                                   "--fit", fit, "--seed-sample", seed, "--out", out])
    assert status == 0, stderr
    assert "S 0.9462 OUT OF RANGE >= 0.97" in stdout and "H (turns) 0.9883 in range 0.97-0.99" in stdout
    page = (out / "report.html").read_text()
    fits_at, norm_at, seed_at = (page.index("<h2>Fitted parameters"), page.index("<h2>Normalisation"),
                                 page.index("<h2>Seed sample"))
    assert fits_at < norm_at < seed_at
    assert "What was measured" not in page         # the analytic fixture is no mock acquisition
    status, _, stderr = _run(["report", h.FIXTURES / "measured_red", h.FIXTURES / "sim_grey",
                              "--fit", tmp_path, "--out", tmp_path / "r2"])
    assert status == 2 and len(stderr.strip().splitlines()) == 1 and "no fit.json there" in stderr
