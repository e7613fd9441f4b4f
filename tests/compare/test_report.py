"""The report as a researcher reads it: captions, error bars, the beam-blocked gap, the
normalisation's uncertainty, H's unit, swatch encoding, source summary, resolution, and where
the report may be written."""

from __future__ import annotations

import colorsys
import html
import json
import re
import shutil

import numpy as np
import pytest
from PIL import Image

from compare.comparison import compare_datasets
from compare.errors import CompareError
from compare.report import FIGURE_DPI, swatch_entries, write_report
from compare.report.curves import gapped as _gapped
from compare.report.figures import inplane_figure as _inplane_figure
from fabric_optics.cli.compare import main
from gonio.data import read_dataset, write_dataset


def _run(argv, capsys):
    status = main([str(a) for a in argv])
    out = capsys.readouterr()
    return status, out.out, out.err


@pytest.fixture(scope="module")
def demo_like(tmp_path_factory, h):
    """measured_red with the meta a real acquisition writes (links with temporary ports)."""
    root = tmp_path_factory.mktemp("demo_like")
    ds = read_dataset(h.FIXTURES / "measured_red")
    ds.meta = {**ds.meta,
               "instrument": {"idn": "KIAM,GPS-1,MOCK0001,2.3", "firmware": "1.4",
                              "modbus": "tcp://127.0.0.1:37371", "serial": "/dev/pts/7"},
               "provenance": {"plan": {"name": "red-cotton", "sha256": "c2d52b3b95016bcf"},
                              "seed": 4, "points_planned": 53, "points_measured": 53,
                              "complete": True}}
    meas = write_dataset(ds, root / "meas")
    out = root / "report"
    comparison = compare_datasets(read_dataset(meas), [read_dataset(h.FIXTURES / "sim_lambert")])
    write_report(comparison, out, svg=True)
    return dict(out=out, comparison=comparison, html=(out / "report.html").read_text())


def test_figures_have_captions_not_file_names(demo_like):
    text = demo_like["html"]
    captions = re.findall(r"<figcaption>(.*?)</figcaption>", text, flags=re.S)
    assert len(captions) == 8
    for j, caption in enumerate(captions, start=1):
        assert caption.startswith(f"<b>Figure {j}.</b> ")
        words = re.sub(r"<[^>]+>|\(figures/[^)]*\)", " ", caption).split()
        assert len(words) > 20, caption               # sentences, not a file name
    alts = re.findall(r"<img alt='([^']*)'", text)
    assert alts and not any(a.endswith(".png") for a in alts)
    assert "Normalisation factor k(lambda)" in text and "Error bars: its standard uncertainty" \
        in text


def test_figures_are_150_dpi_png_and_svg_on_request(demo_like):
    pngs = sorted((demo_like["out"] / "figures").glob("*.png"))
    assert len(pngs) == 8 and FIGURE_DPI >= 150
    for png in pngs:
        dpi = Image.open(png).info["dpi"]
        assert min(dpi) == pytest.approx(150, abs=0.5), png.name
        svg = png.with_suffix(".svg")
        assert svg.is_file() and b"<svg" in svg.read_bytes()[:2000]


def test_a_saved_figure_is_the_picture_savefig_draws(tmp_path):
    """save_figure writes the pixels of matplotlib's own PNG at FIGURE_DPI: an opaque figure as RGB
    (no alpha channel to compress), a figure with transparent parts keeps its alpha."""
    import io
    from pathlib import Path

    import matplotlib.pyplot as plt

    from compare.report.figures import save_figure

    def figure(transparent):
        fig, ax = plt.subplots(figsize=(3, 2))
        ax.plot([0, 1, 2], [1, 0, 2], "o-", label="a")
        ax.fill_between([0, 1, 2], [0, 0, 1], [1, 1, 2], alpha=0.3)
        ax.set_title("title")
        ax.legend()
        fig.tight_layout()
        if transparent:
            fig.patch.set_alpha(0.0)
        return fig

    for transparent, mode in ((False, "RGB"), (True, "RGBA")):
        reference = io.BytesIO()
        fig = figure(transparent)
        fig.savefig(reference, format="png", dpi=FIGURE_DPI)
        plt.close(fig)
        files: dict = {}
        data = save_figure(figure(transparent), Path("figures/x.png"), files=files)
        assert files == {Path("figures/x.png"): data}
        ours, theirs = Image.open(io.BytesIO(data)), Image.open(reference)
        assert ours.mode == mode and ours.size == theirs.size
        assert min(ours.info["dpi"]) == pytest.approx(FIGURE_DPI, abs=0.5)
        np.testing.assert_array_equal(np.asarray(ours.convert("RGBA")), np.asarray(theirs.convert("RGBA")))


def test_the_same_report_gives_the_same_svg_bytes(demo_like, tmp_path):
    """The SVGs carry no random element ids: writing the same comparison again reproduces them
    byte for byte (a report under version control changes only where its data does)."""
    again = tmp_path / "again"
    write_report(demo_like["comparison"], again, svg=True)
    svgs = sorted((demo_like["out"] / "figures").glob("*.svg"))
    assert len(svgs) == 8
    for svg in svgs:
        assert (again / "figures" / svg.name).read_bytes() == svg.read_bytes(), svg.name


def test_error_bars_are_visible_or_said_to_be_hidden(h):
    def figure(u):
        rows = h.in_plane_table(h.red_lobe, incidence=(30.0,), wavelengths=[650.0],
                                u_fn=lambda b: u + 0 * b)
        ds = h.dataset(rows)
        m = ds.in_plane().rename(columns={"beta": "value", "u_beta": "u"})
        return _inplane_figure(m, {}, "t", "y", "m")[1]

    assert figure(1e-5) is True          # +-1e-5 on a 0.4-wide axis: under a 4-pt marker
    assert figure(0.05) is False


def test_html_says_when_bars_are_hidden(h, tmp_path):
    tiny = h.dataset(h.in_plane_table(h.red_lobe, u_fn=lambda b: 1e-6 + 0 * b))
    comparison = compare_datasets(tiny, [read_dataset(h.FIXTURES / "sim_lambert")])
    text = write_report(comparison, tmp_path / "r").read_text()
    assert text.count("are smaller than the markers at this scale") == 4


def test_no_line_across_the_beam_blocked_gap():
    s = np.array([-60, -50, -40, -20, -10, 0, 10.0])
    xs, ys = _gapped(s, s * 2, theta_i=30.0)
    gap = np.flatnonzero(np.isnan(xs))
    assert gap.size == 1 and xs[gap[0] - 1] == -40 and xs[gap[0] + 1] == -20
    # a simulation that holds the retro-direction itself is drawn through it
    with_retro = np.array([-40, -30, -20.0])
    assert not np.isnan(_gapped(with_retro, with_retro, 30.0)[0]).any()
    # a hole in the data is not bridged either
    assert np.isnan(_gapped(np.array([0, 10, 20, 50.0]), np.zeros(4), 0.0)[0]).sum() == 1


def test_the_plotted_model_line_is_broken_and_the_retro_line_labelled(h):
    rows = h.in_plane_table(h.red_lobe, incidence=(30.0,), wavelengths=[650.0])
    ds = h.dataset(rows)
    m = ds.in_plane().rename(columns={"beta": "value", "u_beta": "u"})
    fig, _ = _inplane_figure(m, {"model": m}, "t", "y", "meas")
    ax = fig.axes[0]
    model = [line for line in ax.get_lines() if line.get_label() == "model"]
    assert len(model) == 1 and np.isnan(np.asarray(model[0].get_xdata(), float)).sum() == 1
    texts = [t.get_text().strip() for t in ax.texts]
    assert "retro" in texts and "mirror" in texts
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "beam-blocked (retro-direction)" in legend


def _inside(inner, outer, tol=0.5) -> bool:
    return (inner.x0 >= outer.x0 - tol and inner.y0 >= outer.y0 - tol
            and inner.x1 <= outer.x1 + tol and inner.y1 <= outer.y1 + tol)


@pytest.mark.parametrize("incidence", [(0.0, 30.0, 45.0, 60.0), (0.0, 10.0, 20.0, 30.0, 45.0)])
def test_inplane_layout_keeps_every_label_inside_and_the_legend_clear_of_the_panels(h, incidence):
    """One row (legend in a strip under the panels) and two rows (legend in the first panel):
    every panel's ticks, labels, title and texts, the suptitle and the legend lie inside the
    figure, and a legend under the panels overlaps none of them."""
    from compare.report.figures import tight_layout

    rows = h.in_plane_table(h.red_lobe, incidence=incidence, wavelengths=[650.0])
    m = h.dataset(rows).in_plane().rename(columns={"beta": "value", "u_beta": "u"})
    fig, _ = _inplane_figure(m, {"model a": m, "model b": m.assign(value=m["value"] * 0.8)},
                             "a long title", "beta / pi  (1/sr)", "meas")
    renderer = fig.canvas.get_renderer()
    fig.draw(renderer)
    page = fig.bbox
    panels = [ax.get_tightbbox(renderer) for ax in fig.axes if ax.get_visible()]
    assert panels and all(_inside(b, page) for b in panels)
    # the whole figure's decorations (suptitle too), in inches
    assert _inside(fig.get_tightbbox(renderer), fig.bbox_inches, tol=0.01)
    legend = fig.axes[0].get_legend().get_window_extent(renderer)
    assert _inside(legend, page)
    one_row = len(incidence) <= 4
    if one_row:
        assert all(legend.y1 <= b.y0 + 0.5 for b in panels)    # under every panel, not on one
        # the panels are placed as matplotlib's tight_layout with the strip as its rect
        def pars():
            p = fig.subplotpars
            return p.left, p.right, p.bottom, p.top, p.wspace

        placed = pars()
        fig.tight_layout(rect=(0.0, 0.6 / fig.get_figheight(), 1.0, 1.0))
        assert placed == pytest.approx(pars(), abs=1e-12)
        tight_layout(fig, bottom_in=0.6)                   # and it places them there again
        assert pars() == pytest.approx(placed, abs=1e-12)
    else:
        assert len({round(b.y0) for b in panels}) == 2


def test_normalisation_uncertainty_is_explained_and_carried(h, demo_like):
    text = demo_like["html"]
    assert "not</b> folded into the curve errors" in text
    assert "overall NRMSE at k - u_k .. k + u_k" in text
    # sim_scaled is the measurement times 3.7: at k it agrees exactly, at k(1 +- r) the residual
    # is +-r beta_meas at each wavelength, so NRMSE = sqrt(mean (r beta)^2) / mean beta
    measured = read_dataset(h.FIXTURES / "measured_red")
    comparison = compare_datasets(measured, [read_dataset(h.FIXTURES / "sim_scaled")])
    norm = comparison.normalisations["scaled model"]
    r = dict(zip(norm.wavelength_nm, norm.u_factor / norm.factor, strict=True))
    beta = measured.table["beta"].to_numpy()
    rel = np.array([r[w] for w in measured.table["wavelength_nm"]])
    expected = np.sqrt(np.mean((rel * beta) ** 2)) / np.mean(beta)
    lo, hi = comparison.nrmse_with_factor_shifted("scaled model")
    assert comparison.overall["scaled model"].nrmse < 1e-9
    assert lo == pytest.approx(expected, rel=1e-9) and hi == pytest.approx(expected, rel=1e-9)


def test_hue_unit_is_stated(demo_like):
    text = demo_like["html"]
    assert "<th>H (turns)</th><th>H (deg)</th>" in text
    assert "fraction of a full turn of the hue circle, in [0, 1)" in text
    h_turns = demo_like["comparison"].colour.measured.h
    assert f"<td>{360 * h_turns:.3g}</td>" in text


def test_swatch_labels_describe_the_pixels_shown(demo_like):
    for _name, pixel, hsv in swatch_entries(demo_like["comparison"]):
        assert hsv == pytest.approx(colorsys.rgb_to_hsv(*pixel), abs=1e-12)
    # the pixel is the IEC 61966-2-1 encoding of the linear colour (written out here)
    linear = np.clip(np.asarray(demo_like["comparison"].colour.measured.rgb), 0, None)
    encoded = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(swatch_entries(demo_like["comparison"])[0][1],
                               np.clip(encoded, 0, 1), atol=1e-6)


def test_source_summary_is_readable_without_temporary_links(demo_like):
    text = demo_like["html"]
    assert "tcp://127.0.0.1" not in text and "/dev/pts" not in text
    assert "{&quot;" not in text and '{"' not in text
    assert ("instrument KIAM,GPS-1,MOCK0001,2.3 (firmware 1.4); plan red-cotton (sha256 "
            "c2d52b3b9501...); seed 4; all 53 planned points measured") in html.unescape(text)


# --- where a report may be written ---------------------------------------------------------


@pytest.fixture(scope="module")
def small(tmp_path_factory, h):
    """A small measurement and a simulation of it, on disk and compared, for the tests of where and how a report is
    written (which do not depend on the data's size): one incidence, six in-plane angles, 20 nm steps; a report of
    them costs about a third of one of the analytic fixtures (0.9 CPU s against 2.5)."""
    root = tmp_path_factory.mktemp("small")
    wl = np.arange(400.0, 701.0, 20.0)
    grid = dict(incidence=(0.0,), s_grid=np.array([-40.0, -20.0, -10.0, 10.0, 20.0, 40.0]), wavelengths=wl)
    meas = h.dataset(h.in_plane_table(h.red_lobe, **grid))
    sim = h.dataset(h.in_plane_table(lambda t, s, w: 2.0 * h.red_lobe(t, s, w), **grid), kind="simulated",
                    name="double")
    return dict(meas=write_dataset(meas, root / "meas"), sim=write_dataset(sim, root / "sim"),
                comparison=compare_datasets(meas, [sim]))


def _argv(small, out, *extra):
    return ["report", small["meas"], small["sim"], "--out", out, *extra]


def test_a_foreign_non_empty_folder_is_refused_unless_forced(small, tmp_path, capsys):
    out = tmp_path / "thesis"
    (out / "figures").mkdir(parents=True)
    (out / "metrics.json").write_text("my own numbers")
    (out / "figures" / "spectrum.png").write_bytes(b"my plot")
    status, stdout, err = _run(_argv(small, out), capsys)
    assert status == 2 and err.count("\n") == 1
    assert f"--out {out}: the folder is not empty; pass --force to replace its output" in err
    assert (out / "metrics.json").read_text() == "my own numbers"
    assert (out / "figures" / "spectrum.png").read_bytes() == b"my plot"
    assert not (out / "report.html").exists()
    status, _, err = _run(_argv(small, out, "--force"), capsys)
    assert status == 0, err
    assert json.loads((out / "metrics.json").read_text())["overall"]


def test_a_previous_report_is_replaced_and_its_stale_figures_removed(small, demo_like, tmp_path, capsys):
    out = tmp_path / "rep"
    shutil.copytree(demo_like["out"], out)             # a report this tool wrote, copied not redrawn
    # a figure the previous report wrote (and listed) that the new one will not draw
    report = out / "report.html"
    text = report.read_text()
    report.write_text(text.replace("figures/swatches.png", "figures/swatches.png "
                                   "figures/inplane_999nm.png", 1))
    (out / "figures" / "inplane_999nm.png").write_bytes(b"old")
    (out / "notes.txt").write_text("mine")
    (out / "figures" / "mine.png").write_bytes(b"mine")
    status, _, err = _run(_argv(small, out), capsys)      # an existing report too: only with --force
    assert status == 2 and "pass --force" in err
    assert (out / "figures" / "inplane_999nm.png").read_bytes() == b"old"
    status, _, err = _run(_argv(small, out, "--force"), capsys)
    assert status == 0, err
    assert not (out / "figures" / "inplane_999nm.png").exists()
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "figures" / "mine.png").read_bytes() == b"mine"


def test_write_report_refuses_in_the_library_too(small, tmp_path):
    out = tmp_path / "x"
    out.mkdir()
    (out / "data.csv").write_text("1,2\n")
    comparison = small["comparison"]
    with pytest.raises(CompareError, match=r"\(data.csv\)"):
        write_report(comparison, out)
    shutil.rmtree(out)
    assert write_report(comparison, out).is_file()


def test_a_report_of_the_first_version_is_recognised_as_a_previous_report(small, tmp_path, capsys):
    out = tmp_path / "demo-out-report"
    (out / "figures").mkdir(parents=True)
    (out / "report.html").write_text(
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>\n"
        "<title>Comparison report: red cotton</title>\n<style></style></head><body>\n"
        "<h1>Measurement vs simulation: red cotton</h1>\n"
        "<figure><img alt='inplane_999nm.png' src='data:image/png;base64,AAAA'>"
        "<figcaption>inplane_999nm.png</figcaption></figure>\n</body></html>\n")
    (out / "figures" / "inplane_999nm.png").write_bytes(b"old")
    (out / "metrics.json").write_text("{}")
    status, _, err = _run(_argv(small, out, "--force"), capsys)
    assert status == 0, err
    assert not (out / "figures" / "inplane_999nm.png").exists()
    assert "fabric-optics compare report" in (out / "report.html").read_text()


def test_simulated_lines_carry_their_uncertainty_band(h):
    from matplotlib.collections import PolyCollection

    rows = h.in_plane_table(h.red_lobe, wavelengths=[650.0])
    m = h.dataset(rows).in_plane().rename(columns={"beta": "value", "u_beta": "u"})
    sim = m.assign(u=0.05)
    fig, _ = _inplane_figure(m, {"model": sim}, "t", "y", "meas")
    assert len(fig.axes) == 4 and len({ax.get_position().y0 for ax in fig.axes}) == 1  # one row
    ax = fig.axes[1]                                     # incidence 30: the gap at s = -30
    band = [c for c in ax.collections if isinstance(c, PolyCollection)]
    # +-u around the line, broken like it at the beam-blocked gap (two pieces)
    heights = [np.ptp(p.vertices[:, 1]) for c in band for p in c.get_paths()]
    assert len(heights) == 2 and min(heights) >= 2 * 0.05 / np.pi - 1e-9
    fig_plain, _ = _inplane_figure(m, {"model": sim}, "t", "y", "meas", bands=False)
    assert not [c for c in fig_plain.axes[1].collections if isinstance(c, PolyCollection)]


def test_colour_strips_one_per_dataset_and_incidence(demo_like):
    from compare.report.figures import colour_strips as _colour_strips

    comparison = demo_like["comparison"]
    strips = _colour_strips(comparison)
    incidences = sorted(set(comparison.measured.in_plane()["theta_i"]))
    assert len(strips) == len(incidences) * (1 + len(comparison.simulated))
    assert [s["measured"] for s in strips[:2]] == [True, False]
    for strip in strips:
        # the brightest swatch of a strip shows its largest channel at full scale
        assert strip["pixel"].max() == pytest.approx(1.0)
        assert np.all(np.diff(strip["s"]) > 0) and strip["rgb"].shape == (strip["s"].size, 3)
    measured = [s for s in strips if s["measured"]]
    # the colour is the project's pipeline at that geometry: the measured red dye
    first = measured[0]
    c = comparison.measured.colour_at(first["theta_i"], first["phi_i"], *_in_plane_o(first))
    assert np.allclose(first["rgb"][0], c.rgb)
    # every swatch of a measured and a simulated strip, converted together, is the colour of
    # its own spectrum at its geometry (compare.bands.colour_at, one spectrum at a time)
    from compare.bands import colour_at

    by_label = {**{f"{comparison.measured.name} (measured)": comparison.measured}, **comparison.simulated}
    for strip in (first, next(s for s in strips if not s["measured"])):
        ds = by_label[strip["label"]]
        for k in range(len(strip["s"])):
            c = colour_at(ds, strip["theta_i"], strip["phi_i"],
                          *_in_plane_o({**strip, "s": strip["s"][k:]}), illuminant=comparison.illuminant)
            np.testing.assert_allclose(strip["rgb"][k], c.rgb, rtol=1e-12, atol=1e-15)
            assert strip["h"][k] == pytest.approx(c.h, rel=1e-12, abs=1e-15)
    text = demo_like["html"]
    assert "Colour strips: the colour of each dataset along each in-plane curve" in text
    assert "Hue of linear sRGB (deg; 0/360 red, 300 magenta) at the ends" in text


def _in_plane_o(strip):
    from gonio.data import in_plane_geometry

    return in_plane_geometry(strip["theta_i"], float(strip["s"][0]), strip["phi_i"])


def test_a_section_added_by_api_is_placed_written_listed_and_cleaned_up(small, tmp_path):
    """compare.report.Section: another module adds a section without splicing HTML."""
    from compare.report import Section

    comparison = small["comparison"]
    out = tmp_path / "r"
    extra = [Section("mine", "<h2>My section</h2><p>x &lt; y</p>", figures={"mine.png": b"\x89PNG"},
                     before="curves"),
             Section("last", "<h2>Last words</h2>", before=None)]
    write_report(comparison, out, sections=extra)
    text = (out / "report.html").read_text()
    heads = re.findall(r"<h2>([^<]*)</h2>", text)
    assert heads.index("My section") == heads.index("Curve errors") - 1
    assert heads[-1] == "Last words"
    assert (out / "figures" / "mine.png").read_bytes() == b"\x89PNG"
    files = re.search(r"<meta name='report-files' content='([^']*)'>", text).group(1).split()
    assert "figures/mine.png" in files
    write_report(comparison, out)                       # the next report in the folder drops it
    assert not (out / "figures" / "mine.png").exists()
    assert "My section" not in (out / "report.html").read_text()
