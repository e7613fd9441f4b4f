"""compare with RGB, photometric and relative measurements.

The RGB measurements here are made BY HAND from spectra with colour-science called directly
(``colour.sd_to_XYZ`` -> ``colour.XYZ_to_RGB``), never through ``gonio.data.colour`` or
``compare.bands``, so the comparison's own conversion of a spectral simulation is checked against
an independent call chain.
"""

from __future__ import annotations

import json

import colour
import numpy as np
import pandas as pd
import pytest

from compare.comparison import compare_datasets
from gonio.data import make_dataset, new_meta, write_dataset

CMFS = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
D65 = colour.SDS_ILLUMINANTS["D65"]
SRGB = colour.RGB_COLOURSPACES["sRGB"]
GEO = ["theta_i", "phi_i", "theta_o", "phi_o"]


def hand_xyz(wl, beta):
    """CIE XYZ (Y = 1 for the ideal white) of one spectrum, colour-science directly."""
    sd = colour.SpectralDistribution(dict(zip(np.asarray(wl, float), np.asarray(beta, float), strict=True)))
    with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
        return np.asarray(colour.sd_to_XYZ(sd, CMFS, D65), float) / 100.0


def hand_rgb(wl, beta):
    """Linear sRGB of one spectrum under D65, colour-science directly."""
    return np.asarray(colour.XYZ_to_RGB(hand_xyz(wl, beta), SRGB), float)


def hand_hsv_ratios(rgb):
    hh, ss, vv = colour.RGB_to_HSV(np.asarray(rgb, float))
    return dict(h=float(hh), s=float(ss), v=float(vv), blue_red=rgb[2] / rgb[0],
                green_red=rgb[1] / rgb[0])


def rgb_s(rgb):
    return float(colour.RGB_to_HSV(np.asarray(rgb, float))[1])


def meta(kind, name, **extra):
    m = new_meta(kind, {"name": name}, {"name": "test"}, {"test": True},
                 created="2026-01-01T00:00:00+00:00")
    m.update(extra)
    return m


def to_channels(spectral, channels=("R", "G", "B"), name="rgb", kind="measured", **extra):
    """An RGB (or Y) dataset converted by hand from a spectral one, geometry by geometry."""
    rows = []
    for g, part in spectral.table.groupby(GEO, sort=True):
        wl, beta = part["wavelength_nm"].to_numpy(), part["beta"].to_numpy()
        values = dict(zip("RGB", hand_rgb(wl, beta), strict=True))
        values["Y"] = hand_xyz(wl, beta)[1]
        for c in channels:
            rows.append((*g, c, values[c], 0.001, 10))
    table = pd.DataFrame(rows, columns=GEO + ["channel", "beta", "u_beta", "n"])
    return make_dataset(table, meta(kind, name, **extra))


def dye(wl):
    """A second red dye (different spectrum from the measured one: a real colour difference)."""
    return 0.06 + 0.5 / (1.0 + np.exp(-(np.asarray(wl, float) - 610.0) / 14.0))


@pytest.fixture
def pair(h):
    """Spectral measurement, its hand-made RGB and Y versions, and two spectral simulations."""
    spectral = make_dataset(h.in_plane_table(h.red_lobe), meta("measured", "red"))
    scaled = make_dataset(h.in_plane_table(lambda ti, s, wl: 3.0 * h.red_lobe(ti, s, wl)),
                          meta("simulated", "scaled"))
    other = make_dataset(h.in_plane_table(
        lambda ti, s, wl: 2.0 * (dye(wl) + 0.25 * h.lobe_in_plane(ti, s))),
        meta("simulated", "other dye"))
    return dict(spectral=spectral, rgb=to_channels(spectral, name="red rgb"),
                y=to_channels(spectral, ("Y",), name="red Y"), scaled=scaled, other=other)


def _write(tmp_path, **datasets):
    return {k: write_dataset(ds, tmp_path / k) for k, ds in datasets.items()}


# --- every compare path, spectral and RGB -------------------------------------------------------

@pytest.mark.parametrize("measured", ["spectral", "rgb"])
def test_every_compare_path_with_spectral_and_rgb_measurements(h, pair, tmp_path, capsys,
                                                               measured):
    d = _write(tmp_path, meas=pair[measured], sim=pair["other"], same=pair["scaled"])
    # two simulations in one report
    status, out, err = h.run_cli(["report", d["meas"], d["sim"], d["same"],
                                  "--out", tmp_path / "rep"], capsys)
    assert status == 0, err
    html = (tmp_path / "rep" / "report.html").read_text()
    m = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    assert set(m["curves"]["other dye"]) == {"0", "30", "45", "60"}
    # the shape-identical simulation agrees to rounding, per channel or per wavelength
    assert m["overall"]["scaled"]["nrmse"] < 1e-9
    assert m["overall"]["other dye"]["nrmse"] > 1e-3
    if measured == "rgb":
        assert m["bands"]["channels"] == ["R", "G", "B"]
        factor = m["normalisation"]["factor"]["scaled"]["per_channel"]
        assert factor == pytest.approx({"R": 1 / 3, "G": 1 / 3, "B": 1 / 3}, rel=1e-9)
        assert "converted to the measurement&#x27;s linear sRGB channels R, G, B" in html
        assert "class='note'" in html and "inplane_R.png" in html
        for name in ("scaled", "other dye"):
            assert "converted" in m["bands"]["conversions"][name]
    else:
        assert "bands" not in m and "notes" not in m
        assert "converted to the measurement" not in html
    # CI check: shape and colour match; the level (3 times brighter) is judged on its own
    status, out, _ = h.run_cli(["check", d["meas"], d["same"]], capsys)
    assert status == 1, out
    assert out.count("ok  ") == 3 and "FAIL level ratio max(k_Y, 1/k_Y) = 3 (" in out
    assert "'scaled' matches in shape but not in level: it is 3.00 times brighter" in out
    status, out, _ = h.run_cli(["check", d["meas"], d["same"], "--max-level-ratio", "3.5"], capsys)
    assert status == 0, out
    assert out.count("ok  ") == 4 and "ok   level ratio max(k_Y, 1/k_Y) = 3 (" in out
    assert ("note: 'scaled' is spectral" in out) == (measured == "rgb")
    # one-dataset report
    status, _, err = h.run_cli(["report", d["meas"], "--out", tmp_path / "one"], capsys)
    assert status == 0, err
    one = json.loads((tmp_path / "one" / "metrics.json").read_text())
    assert one["colour"] and all(e["h"] is not None for e in one["colour"])


def test_spectral_simulation_vs_rgb_measurement_same_verdict_as_by_hand(pair):
    """H, S, ratios, dh, ds: the comparison's conversion of the simulation equals converting its
    spectrum by hand with colour-science; the measured colour is the file's channels read
    directly; and the verdict is the spectral-vs-spectral one (the RGB measurement was made from
    the same spectra)."""
    rgb_cmp = compare_datasets(pair["rgb"], [pair["other"]])
    m = rgb_cmp.metrics()["colour"]
    geo = m["geometry"]
    key = (geo["theta_i"], geo["phi_i"], geo["theta_o"], geo["phi_o"])
    sim_rows = pair["other"].spectrum(*key)
    sim = hand_hsv_ratios(hand_rgb(sim_rows["wavelength_nm"], sim_rows["beta"]))
    meas_rows = pair["rgb"].spectrum(*key)
    meas = hand_hsv_ratios(meas_rows.set_index("channel").loc[list("RGB"), "beta"].to_numpy())
    for k in ("h", "s", "blue_red", "green_red"):
        assert m["other dye"][k] == pytest.approx(sim[k], abs=1e-9), k
        assert m["measured"][k] == pytest.approx(meas[k], abs=1e-12), k
    dh = (sim["h"] - meas["h"] + 0.5) % 1.0 - 0.5
    assert m["other dye"]["dh"] == pytest.approx(dh, abs=1e-9)
    assert m["other dye"]["ds"] == pytest.approx(sim["s"] - meas["s"], abs=1e-9)
    assert abs(m["other dye"]["dh"]) + abs(m["other dye"]["ds"]) > 1e-3   # a real difference
    spec = compare_datasets(pair["spectral"], [pair["other"]]).metrics()["colour"]
    assert spec["geometry"] == geo
    for k in ("h", "s", "blue_red", "green_red", "dh", "ds"):
        assert m["other dye"][k] == pytest.approx(spec["other dye"][k], abs=1e-6), k


def test_conversion_propagates_uncertainty_through_the_same_linear_map(pair):
    """u of a converted channel = sqrt(sum_lambda M^2 u^2): with u_beta = 0.001 at every
    wavelength, 0.001 * sqrt(sum M^2), M from colour-science by hand (unit spectra)."""
    cmp_ = compare_datasets(pair["rgb"], [pair["other"]])
    view = cmp_.view("other dye")
    wl = pair["other"].wavelengths_nm
    eye = np.eye(wl.size)
    m = np.array([hand_rgb(wl, eye[j]) for j in range(wl.size)]).T   # 3 x n
    expected = 0.001 * np.sqrt((m ** 2).sum(axis=1))
    got = view.table.groupby("wavelength_nm")["u_beta"].first().to_numpy()
    assert got == pytest.approx(expected, rel=1e-9)


def test_rgb_simulation_against_rgb_measurement(h, pair, tmp_path, capsys):
    sim = to_channels(pair["other"], name="other rgb", kind="simulated")
    d = _write(tmp_path, meas=pair["rgb"], sim=sim)
    status, out, _ = h.run_cli(["check", d["meas"], d["sim"], "--max-nrmse", "1",
                                "--max-hue-diff", "1", "--max-sat-diff", "1",
                                "--max-level-ratio", "10"], capsys)
    assert status == 0, out
    assert "note:" not in out   # same space, same channels: nothing converted
    by_rgb = compare_datasets(pair["rgb"], [sim]).metrics()["colour"]["other rgb"]
    by_spectrum = compare_datasets(pair["rgb"], [pair["other"]]).metrics()["colour"]["other dye"]
    for k in ("h", "s", "blue_red", "green_red", "dh", "ds", "v"):
        assert by_rgb[k] == pytest.approx(by_spectrum[k], abs=1e-9), k


def test_rgb_simulation_in_another_colour_space_is_converted(pair):
    """Adobe RGB channels of the same colours, converted back to sRGB by the comparison."""
    sim = to_channels(pair["other"], name="other", kind="simulated")
    m = colour.matrix_RGB_to_RGB(SRGB, colour.RGB_COLOURSPACES["Adobe RGB (1998)"],
                                 chromatic_adaptation_transform="Bradford")
    wide = sim.table.pivot_table(index=GEO, columns="channel", values="beta")[["R", "G", "B"]]
    adobe = wide.to_numpy() @ m.T
    rows = [(*g, c, v, 0.001, 10) for g, vals in zip(wide.index, adobe, strict=True)
            for c, v in zip("RGB", vals, strict=True)]
    adobe_ds = make_dataset(pd.DataFrame(rows, columns=GEO + ["channel", "beta", "u_beta", "n"]),
                            meta("simulated", "adobe", colour_space="linear Adobe RGB (1998)"))
    a = compare_datasets(pair["rgb"], [adobe_ds])
    b = compare_datasets(pair["rgb"], [sim])
    assert "converted from linear Adobe RGB (1998)" in a.notes()[0]
    # the published sRGB and Adobe RGB matrices round-trip only to ~3e-5 (their rounding)
    assert a.overall["adobe"].nrmse == pytest.approx(b.overall["other"].nrmse, rel=1e-3)
    ca, cb = a.metrics()["colour"]["adobe"], b.metrics()["colour"]["other"]
    for k in ("h", "s", "dh", "ds"):
        assert ca[k] == pytest.approx(cb[k], abs=2e-4), k
    # not converting would be visibly wrong: the Adobe channels read as sRGB are another colour
    geo = a.metrics()["colour"]["geometry"]
    rows = adobe_ds.spectrum(geo["theta_i"], geo["phi_i"], geo["theta_o"], geo["phi_o"])
    assert abs(ca["s"] - rgb_s(rows["beta"].to_numpy())) > 1e-2


# --- photometric (Y) ---------------------------------------------------------------------------

def test_photometric_measurement_is_compared_on_y_only_without_colour(h, pair, tmp_path, capsys):
    d = _write(tmp_path, meas=pair["y"], sim=pair["scaled"], other=pair["other"])
    status, out, _ = h.run_cli(["check", d["meas"], d["sim"], "--max-level-ratio", "3.5"], capsys)
    assert status == 0, out
    assert "ok   level ratio max(k_Y, 1/k_Y) = 3 (" in out   # the level is judged on Y too (3 times)
    assert "overall NRMSE" in out and "hue" not in out.replace("(no H, S, V)", "")
    assert "converted to the measurement's the photometric channel Y" not in out
    assert "converted to the measurement's photometric channel Y (its CIE Y)" in out
    assert "makes no colour statement" in out
    status, _, err = h.run_cli(["report", d["meas"], d["other"], "--out", tmp_path / "r"], capsys)
    assert status == 0, err
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["colour"] == {} and m["bands"]["channels"] == ["Y"]
    assert set(m["normalisation"]["factor"]["other dye"]["per_channel"]) == {"Y"}
    html = (tmp_path / "r" / "report.html").read_text()
    assert "No colour statement" in html and "swatches.png" not in html
    # the Y curves: the simulation's Y is its CIE Y computed by hand, times k(Y)
    c = compare_datasets(pair["y"], [pair["other"]])
    frame = c.frames["other dye"]
    row = frame.iloc[len(frame) // 2]
    spec = pair["other"].spectrum(*(row[g] for g in GEO))
    assert row["beta_sim_raw"] == pytest.approx(hand_xyz(spec["wavelength_nm"],
                                                         spec["beta"])[1], rel=1e-9)


# --- relative measurements ----------------------------------------------------------------------

@pytest.mark.parametrize("measured", ["spectral", "rgb"])
def test_relative_measurement_refuses_v_with_a_note(h, pair, tmp_path, capsys, measured):
    base = pair[measured]
    relative = base.with_values(base.table["beta"] * 1234.0, base.table["u_beta"] * 1234.0,
                                meta_update={"relative": True})
    d = _write(tmp_path, meas=relative, sim=pair["other"])
    status, _, err = h.run_cli(["report", d["meas"], d["sim"], "--out", tmp_path / "r"], capsys)
    assert status == 0, err
    m = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert m["relative"] is True
    assert m["colour"]["measured"]["v"] is None and m["colour"]["other dye"]["v"] is None
    assert m["colour"]["other dye"]["dv"] is None
    # normalised like any other: shapes only, so the verdict equals the absolute one
    absolute = compare_datasets(base, [pair["other"]]).metrics()
    assert m["overall"]["other dye"]["nrmse"] == pytest.approx(
        absolute["overall"]["other dye"]["nrmse"], rel=1e-9)
    for k in ("h", "s", "dh", "ds", "blue_red", "green_red"):
        assert m["colour"]["other dye"][k] == pytest.approx(absolute["colour"]["other dye"][k],
                                                            abs=1e-9)
    html = (tmp_path / "r" / "report.html").read_text()
    assert "V and dv refused" in html
    assert any("relative" in n and "V and dv are refused" in n for n in m["notes"])
    # check: H and S thresholds still apply to a relative measurement, V is never stated
    status, out, _ = h.run_cli(["check", d["meas"], d["sim"], "--max-nrmse", "1",
                                "--max-hue-diff", "0", "--max-sat-diff", "1"], capsys)
    assert status == 1 and "FAIL |hue difference|" in out
    assert "V and dv are refused" in out


# --- combinations that cannot be compared: one clear line, exit 2 --------------------------------

def _bad(pair):
    y_sim = to_channels(pair["other"], ("Y",), name="y sim", kind="simulated")
    rgb_sim = to_channels(pair["other"], name="rgb sim", kind="simulated")
    t = pair["other"].table
    narrow = make_dataset(t[(t["wavelength_nm"] >= 450) & (t["wavelength_nm"] <= 650)],
                          meta("simulated", "narrow"))
    return {"rgb measured vs Y-only simulation": (pair["rgb"], y_sim, "no channel in common"),
            "spectral measured vs RGB simulation": (pair["spectral"], rgb_sim,
                                                    "cannot be recovered from colour channels"),
            # 450..650 nm sees only ~64 % of the blue channel (a silent wrong colour otherwise)
            "rgb measured vs a spectrum too narrow for the channels": (
                pair["rgb"], narrow, "covers 450..650 nm, which carries only 63.")}


def test_a_spectrum_on_the_visible_range_is_enough(pair):
    t = pair["other"].table
    trimmed = make_dataset(t[(t["wavelength_nm"] >= 410) & (t["wavelength_nm"] <= 690)],
                           meta("simulated", "trimmed"))
    full = compare_datasets(pair["rgb"], [pair["other"]]).metrics()["colour"]["other dye"]
    cut = compare_datasets(pair["rgb"], [trimmed]).metrics()["colour"]["trimmed"]
    assert cut["h"] == pytest.approx(full["h"], abs=0.01)


@pytest.mark.parametrize("command", ["check", "report"])
@pytest.mark.parametrize("case", ["rgb measured vs Y-only simulation",
                                  "spectral measured vs RGB simulation",
                                  "rgb measured vs a spectrum too narrow for the channels"])
def test_incompatible_bands_exit_2_with_one_line(h, pair, tmp_path, capsys, case, command):
    meas, sim, expected = _bad(pair)[case]
    d = _write(tmp_path, meas=meas, sim=sim)
    argv = [command, d["meas"], d["sim"]] + (["--out", tmp_path / "r"]
                                             if command == "report" else [])
    status, out, err = h.run_cli(argv, capsys)
    assert status == 2
    assert err.startswith(f"compare {command}: error: ") and err.count("\n") == 1, err
    assert expected in err and str(d["sim"]) in err and "Traceback" not in err
    assert not (tmp_path / "r" / "report.html").exists()
