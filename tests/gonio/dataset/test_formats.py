"""Importers: RGL .bsdf against Mitsuba 3, MERL round trips, pgII known values, fuzzing."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fabric_optics.cli.gonio import main as gonio_main
from gonio.data import make_dataset, new_meta, read_dataset, write_dataset
from gonio.data.formats import FormatError
from gonio.data.formats.merl import MERL_SHAPE, half_diff, read_merl, write_merl
from gonio.data.formats.pgii import parse_pgii, pgii_dataset, read_pgii
from gonio.data.formats.rgl_bsdf import read_rgl_bsdf
from gonio.data.formats.tensor import parse_tensor_bytes

FELT = Path(__file__).resolve().parents[3] / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"


def _random_directions(rng, n):
    z = rng.uniform(0.02, 1.0, n)
    p = rng.uniform(0.0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    return np.stack([s * np.cos(p), s * np.sin(p), z], axis=-1)


@pytest.fixture(scope="module")
def felt():
    return read_rgl_bsdf(FELT)


def test_felt_matches_mitsuba_measured_plugin(felt):
    """>= 1000 random direction pairs: our numpy evaluation equals Mitsuba 3's `measured`
    plugin (scalar_rgb variant, float32) to float32 accuracy."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    bsdf = mi.load_dict({"type": "measured", "filename": str(FELT)})
    rng = np.random.default_rng(7)
    wi, wo = _random_directions(rng, 1200), _random_directions(rng, 1200)
    ours = felt.eval_cos(wi, wo)
    ctx = mi.BSDFContext()
    ref = np.empty_like(ours)
    for k, (a, b) in enumerate(zip(wi, wo, strict=True)):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*a)
        ref[k] = list(bsdf.eval(ctx, si, mi.Vector3f(*b)))
    assert np.all(ref > 0)
    # Mitsuba computes in float32: relative rounding ~1e-7 per operation, a few hundred ops
    np.testing.assert_allclose(ours, ref, rtol=1e-4, atol=1e-7)
    # and a wrong cosine convention would be off by cos(theta_o), far outside that tolerance
    assert np.max(np.abs(ours / wo[:, 2:] - ref) / ref) > 0.1


def test_felt_is_green_and_physical(felt):
    assert felt.isotropic and not felt.is_spectral
    # energy: directional albedo (cosine-weighted hemispherical integral of f_r) below 1
    rng = np.random.default_rng(3)
    n = 20000
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    wo = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], axis=-1)
    for theta in (0.0, 40.0, 60.0):
        wi = np.array([np.sin(np.radians(theta)), 0.0, np.cos(np.radians(theta))])
        f_cos = felt.eval_cos(np.broadcast_to(wi, wo.shape), wo)
        # cosine sampling: albedo = mean(f_r cos / pdf) with pdf = cos/pi -> mean(pi f_r)
        samples = np.pi * f_cos / wo[:, 2:]
        albedo = samples.mean(axis=0)
        se = samples.std(axis=0) / np.sqrt(n)
        assert np.all(albedo + 4 * se < 1.0), (theta, albedo)
        assert albedo[1] > albedo[0] > albedo[2]        # green felt: G > R > B
    # reciprocity: the measured data are only approximately reciprocal; the ratio stays near 1
    wi, wo = _random_directions(rng, 400), _random_directions(rng, 400)
    keep = (wi[:, 2] > 0.5) & (wo[:, 2] > 0.5)
    fwd = felt.eval_cos(wi[keep], wo[keep]) / wo[keep, 2:]
    bwd = felt.eval_cos(wo[keep], wi[keep]) / wi[keep, 2:]
    assert np.median(np.abs(np.log(fwd / bwd))) < 0.1


def test_felt_colour_from_channels(tmp_path):
    assert gonio_main(["import", "rgl-bsdf", str(FELT), "--out", str(tmp_path / "felt")]) == 0
    ds = read_dataset(tmp_path / "felt")
    assert ds.is_rgb and ds.channels == ("R", "G", "B") and ds.colour_space == "linear sRGB"
    c = ds.colour_at(0.0, 0.0, 10.0, 180.0)
    assert 0.2 < c.h < 0.45                     # green hue
    rows = ds.spectrum(0.0, 0.0, 10.0, 180.0).set_index("channel")["beta"]
    assert rows["G"] > rows["R"] > rows["B"]
    # in-plane default: the file's own incidence angles, but for the near-grazing last one
    own = read_rgl_bsdf(FELT).theta_i_deg
    assert own[-1] > 89.9999 and own[-2] < 89
    assert np.allclose(np.unique(ds.table.theta_i), own[:-1], atol=1e-6)


def test_import_errors_are_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.bsdf"
    bad.write_bytes(FELT.read_bytes()[:5000])
    assert gonio_main(["import", "rgl-bsdf", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bad.bsdf" in err and "byte offset" in err
    assert "Traceback" not in err


def _f_analytic(theta_h, theta_d, phi_d):
    """A smooth positive analytic BRDF of the half/difference angles (per channel)."""
    base = 0.2 + 0.5 * np.cos(theta_h) ** 8 + 0.05 * np.cos(theta_d) * (1 + 0.3 * np.cos(phi_d))
    return np.stack([base, 0.8 * base, 0.5 * base], axis=-1) / np.pi


def test_merl_round_trip_exact(tmp_path):
    path = write_merl(tmp_path / "a.binary", _f_analytic)
    brdf = read_merl(path)
    raw = np.frombuffer(path.read_bytes()[12:], dtype="<f8").reshape((3,) + MERL_SHAPE)
    table = np.moveaxis(_f_analytic(*np.meshgrid(
        (np.arange(90) / 90.0) ** 2 * np.pi / 2, np.arange(90) / 90.0 * np.pi / 2,
        np.arange(180) / 180.0 * np.pi, indexing="ij")), -1, 0)
    scale = np.array([1 / 1500, 1.15 / 1500, 1.66 / 1500])[:, None, None, None]
    assert np.array_equal(raw, table / scale)
    np.testing.assert_allclose(brdf.table, table, rtol=1e-15)
    # writing what was read gives the same bytes
    again = write_merl(tmp_path / "b.binary", brdf.table)
    assert again.read_bytes() == path.read_bytes()
    # lookups land in the bin of the geometry: equal to the table at the bin's indices
    rng = np.random.default_rng(1)
    wi, wo = _random_directions(rng, 500), _random_directions(rng, 500)
    th, td, pd_ = half_diff(wi, wo)
    f = brdf.f_r(wi, wo)
    i_h = np.clip(np.sqrt(th / (np.pi / 2) * 90 * 90).astype(int), 0, 89)   # BRDFRead.cpp
    i_d = np.clip((td / (np.pi / 2) * 90).astype(int), 0, 89)
    i_p = np.clip((np.where(pd_ < 0, pd_ + np.pi, pd_) / np.pi * 180).astype(int), 0, 179)
    np.testing.assert_array_equal(f, np.moveaxis(brdf.table[:, i_h, i_d, i_p], 0, -1))


def test_merl_import_to_dataset(tmp_path):
    path = write_merl(tmp_path / "a.binary", _f_analytic)
    out = tmp_path / "ds"
    assert gonio_main(["import", "merl", str(path), "--out", str(out)]) == 0
    ds = read_dataset(out)
    assert ds.is_rgb and len(ds.geometries()) > 100
    np.testing.assert_allclose(ds.table[ds.table.channel == "G"].beta.to_numpy(),
                               0.8 * ds.table[ds.table.channel == "R"].beta.to_numpy(), rtol=1e-9)  # %.10g CSV


PGII = """#sample_name "test felt"
#intheta 30
#format: theta phi {unit}
{lambda_line}{rows}"""


def _pgii_text(unit, rows, lambda_line=""):
    return PGII.format(unit=unit, lambda_line=lambda_line,
                       rows="".join(" ".join(f"{v:.10g}" for v in r) + "\n" for r in rows))


def test_pgii_known_values(tmp_path):
    rows = [(0.0, 0.0, 0.1), (20.0, 0.0, 0.2), (160.0, 0.0, 0.3)]   # 160 = 20 on the other side
    (tmp_path / "a.txt").write_text(_pgii_text("BSDF", rows))
    dsa = pgii_dataset([read_pgii(tmp_path / "a.txt")])
    assert dsa.is_rgb and dsa.channels == ("Y",) and not dsa.relative
    t = dsa.table.sort_values(["theta_o", "phi_o"]).reset_index(drop=True)
    np.testing.assert_allclose(t.beta, np.pi * np.array([0.1, 0.2, 0.3]))
    assert t.theta_o.tolist() == [0.0, 20.0, 20.0] and t.phi_o.tolist()[1:] == [0.0, 180.0]
    # DSF = f_r cos theta_o; spectral variant
    rows2 = [(0.0, 0.0, 0.1, 0.2), (60.0, 0.0, 0.05, 0.1)]
    (tmp_path / "b.txt").write_text(_pgii_text("DSF", rows2, "#lambda=450 650\n"))
    dsb = pgii_dataset([read_pgii(tmp_path / "b.txt")])
    s = dsb.spectrum(30.0, 0.0, 60.0, 0.0)
    np.testing.assert_allclose(s.beta, np.pi * np.array([0.05, 0.1]) / 0.5)
    # raw detector units -> relative dataset; with a scale -> absolute
    (tmp_path / "c.txt").write_text(_pgii_text("[uA]", rows))
    assert pgii_dataset([read_pgii(tmp_path / "c.txt")]).relative
    dsc = pgii_dataset([read_pgii(tmp_path / "c.txt")], scale=2.0)
    assert not dsc.relative and np.isclose(dsc.table.beta.max(), np.pi * 0.6)


def test_pgii_white_reference_makes_raw_currents_absolute(tmp_path):
    """A Lambertian sample of f_r = 0.2 and a white standard of reflectance 0.98 read by one
    detector (I = K f_r cos theta_i) at different incidences: the import recovers f_r."""
    K = 37.0
    f_sample, rho_w = 0.2, 0.98
    white = PGII.replace("#intheta 30", "#intheta 10").format(
        unit="[uA]", lambda_line="#lambda=450 650\n",
        rows="".join(f"{t} 0 {K * rho_w / np.pi * np.cos(np.radians(10)):.12g} "
                     f"{0.5 * K * rho_w / np.pi * np.cos(np.radians(10)):.12g}\n" for t in (0, 20, 40, 75)))
    (tmp_path / "white.txt").write_text(white)
    sample = PGII.replace("#intheta 30", "#intheta 50").format(
        unit="[uA]", lambda_line="#lambda=450 650\n",
        rows="".join(f"{t} 0 {K * f_sample * np.cos(np.radians(50)):.12g} "
                     f"{0.5 * K * f_sample * np.cos(np.radians(50)):.12g}\n" for t in (0, 30, 60)))
    (tmp_path / "s.txt").write_text(sample)
    out = tmp_path / "ds"
    assert gonio_main(["import", "pgii", str(tmp_path / "s.txt"), "--white", str(tmp_path / "white.txt"),
                       "--white-reflectance", str(rho_w), "--out", str(out)]) == 0
    from gonio.data import read_dataset

    ds = read_dataset(out)
    assert not ds.relative
    np.testing.assert_allclose(ds.table.beta, np.pi * f_sample, rtol=1e-9)
    assert ds.meta["provenance"]["white_reflectance"] == rho_w
    # the wrong unit for a reference is one clear line
    (tmp_path / "bsdf.txt").write_text(_pgii_text("BSDF", [(0, 0, 0.1)], "#lambda=450 650\n").replace(
        "0 0 0.1", "0 0 0.1 0.1"))
    assert gonio_main(["import", "pgii", str(tmp_path / "s.txt"), "--white", str(tmp_path / "bsdf.txt"),
                       "--out", str(tmp_path / "x")]) == 2


def test_pgii_duplicate_direction_names_both_lines(tmp_path, capsys):
    # line 5 (theta 20, phi 0) and line 7 (theta 160 mirrored: theta 20, phi 180) are distinct;
    # line 8 (theta 200 - 40 = 160, phi 180 -> theta 20, phi 0) repeats line 5
    (tmp_path / "d.txt").write_text(_pgii_text("BSDF", [(0, 0, 0.1), (20, 0, 0.2), (40, 0, 0.3), (160, 0, 0.2),
                                                        (160, 180, 0.25)]))
    assert gonio_main(["import", "pgii", str(tmp_path / "d.txt"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "d.txt" in err and "lines 5 and 8" in err, err


def test_pgii_error_names_line(tmp_path, capsys):
    (tmp_path / "a.txt").write_text(_pgii_text("BSDF", [(0, 0, 1)]) + "10 20 abc\n")
    assert gonio_main(["import", "pgii", str(tmp_path / "a.txt"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "a.txt" in err and "line 5" in err and "'abc'" in err and err.count("\n") == 1


def test_rgb_dataset_round_trip_and_spectral_bytes_unchanged(tmp_path):
    table = pd.DataFrame({"theta_i": 0.0, "phi_i": 0.0, "theta_o": [10.0] * 3,
                          "phi_o": 180.0, "channel": ["B", "R", "G"], "beta": [0.1, 0.8, 0.01],
                          "u_beta": 0.001, "n": 4})
    ds = make_dataset(table, new_meta("measured", {"name": "rgb"}, created="2024-01-01T00:00:00"))
    write_dataset(ds, tmp_path / "rgb")
    back = read_dataset(tmp_path / "rgb")
    assert back.channels == ("R", "G", "B") and back.meta["colour_space"] == "linear sRGB"
    assert (tmp_path / "rgb" / "radiance.csv").read_text().splitlines()[0] == \
        "theta_i,phi_i,theta_o,phi_o,channel,beta,u_beta,n"
    c = back.colour_at(0, 0, 10, 180)
    assert c.rgb == (0.8, 0.01, 0.1)
    # a bad channel names the row and the column
    bad = (tmp_path / "rgb" / "radiance.csv").read_text().replace(",G,", ",X,")
    (tmp_path / "rgb" / "radiance.csv").write_text(bad)
    (tmp_path / "rgb" / "meta.json").write_text(
        (tmp_path / "rgb" / "meta.json").read_text().replace('"sha256"', '"sha256_old"'))
    with pytest.raises(Exception) as info:
        read_dataset(tmp_path / "rgb")
    assert "row 3" in str(info.value) and "channel" in str(info.value)


def test_spectral_fixture_bytes_unchanged(tmp_path):
    src = Path(__file__).resolve().parents[3] / "fixtures" / "analytic" / "measured_red"
    write_dataset(read_dataset(src), tmp_path / "copy")
    assert (tmp_path / "copy" / "radiance.csv").read_bytes() == (src / "radiance.csv").read_bytes()


# --- fuzzing: only FormatError (one clear message), never a crash or a hang ----------------

_FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
_FELT_HEAD = FELT.read_bytes()[:4096]


@_FUZZ
@given(st.binary(max_size=600), st.integers(0, 4096))
def test_fuzz_tensor_reader(noise, cut):
    data = _FELT_HEAD[:cut] + noise
    try:
        fields = parse_tensor_bytes(data, "fuzz.bsdf")
    except FormatError as exc:
        assert "fuzz.bsdf" in str(exc)
        return
    assert isinstance(fields, dict)


@_FUZZ
@given(st.integers(0, 200), st.binary(min_size=1, max_size=8))
def test_fuzz_tensor_header_bytes(position, patch):
    data = bytearray(_FELT_HEAD)
    data[position:position + len(patch)] = patch
    try:
        parse_tensor_bytes(bytes(data), "fuzz.bsdf")
    except FormatError as exc:
        assert "byte offset" in str(exc) or "fuzz.bsdf" in str(exc)


@_FUZZ
@given(st.lists(st.text(alphabet="0123456789 .-#eE\tabcthpiBSDF:=[]uA_", max_size=30),
                max_size=12))
def test_fuzz_pgii_reader(lines):
    text = "#intheta 30\n#format: theta phi BSDF\n" + "\n".join(lines)
    try:
        f = parse_pgii(text, "fuzz.txt")
    except FormatError as exc:
        assert "fuzz.txt" in str(exc)
        return
    assert np.all(np.isfinite(f.values)) and np.all((f.theta_o >= 0) & (f.theta_o <= 90))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 3 * 90 * 90 * 180 * 8 + 20), st.binary(max_size=16))
def test_fuzz_merl_reader(tmp_path_factory, cut, tail):
    path = tmp_path_factory.mktemp("merl") / "f.binary"
    data = struct.pack("<3i", *MERL_SHAPE) + b"\0" * (3 * 90 * 90 * 180 * 8)
    path.write_bytes(data[:cut] + tail)
    try:
        read_merl(path)
    except FormatError as exc:
        assert "f.binary" in str(exc) and "byte offset" in str(exc)
