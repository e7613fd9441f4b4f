"""The radiance-coefficient dataset: round trips, atomicity, precise errors, views, interpolation."""

from __future__ import annotations

import json
import os

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gonio.data import (
    COLUMNS,
    DatasetError,
    in_plane_geometry,
    make_dataset,
    new_meta,
    read_dataset,
    signed_angle,
    write_dataset,
)
from gonio.data import dataset as dsm

WL = np.arange(390.0, 711.0, 10.0)


def beta_model(theta_i, s, wl):
    """A function linear in (theta_i, s, wavelength): linear interpolation must recover it exactly."""
    return 0.2 + 0.002 * theta_i + 0.001 * s + 0.0005 * (wl - 390.0)


def in_plane_table(incidences=(0.0, 30.0, 45.0, 60.0), wavelengths=WL, phi_i=0.0):
    rows = []
    for ti in incidences:
        for s in np.arange(-60.0, 71.0, 10.0):
            if abs(s + ti) < 5.0:  # the beam-blocked direction is never measured
                continue
            to, po = in_plane_geometry(ti, s, phi_i)
            for w in wavelengths:
                rows.append((ti, phi_i, to, po, w, beta_model(ti, s, w), 0.01, 16))
    return pd.DataFrame(rows, columns=COLUMNS)


def meta(name="sample A"):
    return new_meta("measured", {"name": name}, {"model": "test"}, {"seed": 1},
                    created="2026-01-01T00:00:00+00:00")


@pytest.fixture
def dataset_dir(tmp_path):
    ds = make_dataset(in_plane_table(), meta())
    return write_dataset(ds, tmp_path / "run")


def test_round_trip_is_exact_and_byte_stable(dataset_dir, tmp_path):
    ds = read_dataset(dataset_dir)
    original = make_dataset(in_plane_table(), meta())
    pd.testing.assert_frame_equal(ds.table, original.table)
    assert ds.kind == "measured" and ds.name == "sample A"
    assert ds.meta["wavelengths_nm"] == list(WL)
    # rewriting what was read gives byte-identical files
    write_dataset(ds, tmp_path / "again")
    assert (tmp_path / "again" / "radiance.csv").read_bytes() == \
        (dataset_dir / "radiance.csv").read_bytes()
    assert not [p for p in dataset_dir.iterdir() if p.name.endswith(".tmp")]


def test_writing_keeps_other_files_in_the_run_directory(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "journal.jsonl").write_text('{"point": 1}\n')
    write_dataset(make_dataset(in_plane_table(), meta()), run)
    assert (run / "journal.jsonl").read_text() == '{"point": 1}\n'


def test_interrupted_write_is_detected_not_silently_mixed(dataset_dir, monkeypatch):
    """A crash between the two renames leaves new values with old metadata: reading must refuse."""
    other = make_dataset(in_plane_table(incidences=(0.0, 30.0)), meta())
    real_replace = os.replace
    calls = []

    def crash_on_meta(src, dst):
        calls.append(dst)
        if str(dst).endswith("meta.json"):
            raise KeyboardInterrupt("killed")
        return real_replace(src, dst)

    monkeypatch.setattr(dsm.os, "replace", crash_on_meta)
    with pytest.raises(KeyboardInterrupt):
        write_dataset(other, dataset_dir)
    monkeypatch.setattr(dsm.os, "replace", real_replace)
    with pytest.raises(DatasetError, match="checksum"):
        read_dataset(dataset_dir)
    assert not [p for p in dataset_dir.iterdir() if p.name.endswith(".tmp")]


def _rewrite_csv(dataset_dir, text):
    (dataset_dir / "radiance.csv").write_text(text)
    m = json.loads((dataset_dir / "meta.json").read_text())
    m.pop("files", None)  # hand-edited on purpose: no checksum
    (dataset_dir / "meta.json").write_text(json.dumps(m))


@pytest.mark.parametrize("mutate, expected", [
    (lambda lines: [lines[0].replace(",u_beta", "")] + [l.rsplit(",", 2)[0] + "," + l.rsplit(",", 1)[1] for l in lines[1:]],
     r"missing column\(s\) u_beta"),
    (lambda lines: lines[:3] + [lines[3].replace(lines[3].split(",")[5], "nan", 1)] + lines[4:],
     r"row 4, column 'beta': value 'nan' is not a finite number"),
    (lambda lines: lines[:3] + [lines[3].replace(lines[3].split(",")[5], "abc", 1)] + lines[4:],
     r"row 4, column 'beta': value 'abc'"),
    (lambda lines: lines + [lines[5]], r"duplicate geometry and wavelength .* also on row"),
    (lambda lines: [lines[0]], r"no data rows"),
    (lambda lines: lines[:2] + ["95" + lines[2][lines[2].index(","):]] + lines[3:],
     r"row 3, column 'theta_i': value 95 must be in \[0, 90\]"),
    (lambda lines: [",".join(reversed(lines[0].split(",")))] + lines[1:], r"in this order"),
])
def test_bad_csv_gives_one_precise_error(dataset_dir, mutate, expected):
    lines = (dataset_dir / "radiance.csv").read_text().splitlines()
    _rewrite_csv(dataset_dir, "\n".join(mutate(lines)) + "\n")
    with pytest.raises(DatasetError, match=expected) as info:
        read_dataset(dataset_dir)
    assert "radiance.csv" in str(info.value)


def test_empty_files_and_unknown_schema(dataset_dir):
    csv = dataset_dir / "radiance.csv"
    saved = csv.read_bytes()
    csv.write_bytes(b"")
    with pytest.raises(DatasetError, match="radiance.csv: file is empty"):
        read_dataset(dataset_dir)
    csv.write_bytes(saved)
    m = json.loads((dataset_dir / "meta.json").read_text())
    m["schema"] = "radiance-dataset/9"
    (dataset_dir / "meta.json").write_text(json.dumps(m))
    with pytest.raises(DatasetError, match=r"meta.json: unknown schema 'radiance-dataset/9'"):
        read_dataset(dataset_dir)
    (dataset_dir / "meta.json").write_text("{not json")
    with pytest.raises(DatasetError, match=r"meta.json, row 1: invalid JSON"):
        read_dataset(dataset_dir)


def test_meta_wavelengths_must_match_the_table(dataset_dir):
    m = json.loads((dataset_dir / "meta.json").read_text())
    m["wavelengths_nm"] = m["wavelengths_nm"][:-1]
    (dataset_dir / "meta.json").write_text(json.dumps(m))
    with pytest.raises(DatasetError, match="wavelengths_nm.*do not match"):
        read_dataset(dataset_dir)


def test_missing_directory_and_files(tmp_path):
    with pytest.raises(DatasetError, match="no such dataset directory"):
        read_dataset(tmp_path / "nope")
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "radiance.csv").write_text(",".join(COLUMNS) + "\n")
    with pytest.raises(DatasetError, match="meta.json: file is missing"):
        read_dataset(tmp_path / "half")


def test_normal_direction_is_one_geometry_whatever_phi_o():
    table = in_plane_table(incidences=(30.0,), wavelengths=[500.0])
    table = table[table["theta_o"] != 0.0]
    extra = table.iloc[[0]].copy()
    extra[["theta_o", "phi_o"]] = [0.0, 17.0]
    twin = extra.copy()
    twin["phi_o"] = 250.0
    with pytest.raises(DatasetError, match="duplicate"):
        make_dataset(pd.concat([table, extra, twin]), meta())
    ds = make_dataset(pd.concat([table, extra]), meta())
    normal = ds.table[ds.table["theta_o"] == 0.0]
    assert normal["phi_o"].tolist() == [180.0]


def test_signed_angle_convention():
    assert signed_angle(30, 0, 40, 180) == 40.0
    assert signed_angle(30, 0, 40, 0) == -40.0
    assert signed_angle(30, 90, 40, 270) == 40.0
    assert signed_angle(30, 0, 0, 123) == 0.0
    assert np.isnan(signed_angle(30, 0, 40, 90))
    assert in_plane_geometry(30.0, 20.0, 350.0) == (20.0, 170.0)


def test_in_plane_view(dataset_dir):
    ds = read_dataset(dataset_dir)
    curve = ds.in_plane(theta_i=30.0, wavelength_nm=500.0)
    assert curve["s"].tolist() == [s for s in range(-60, 71, 10) if s != -30]
    np.testing.assert_allclose(curve["beta"], beta_model(30.0, curve["s"], 500.0))
    spectrum = ds.spectrum(45.0, 0.0, 20.0, 180.0)
    np.testing.assert_allclose(spectrum["beta"], beta_model(45.0, 20.0, WL))
    with pytest.raises(DatasetError, match="no data at theta_i=30"):
        ds.spectrum(30.0, 0.0, 30.0, 0.0)  # the blocked direction


def test_interpolation_recovers_a_linear_function_and_refuses_outside(dataset_dir):
    ds = read_dataset(dataset_dir)
    rng = np.random.default_rng(3)
    ti = rng.uniform(0.0, 60.0, 50)
    s = rng.uniform(-55.0, 65.0, 50)
    wl = rng.uniform(390.0, 710.0, 50)
    to, po = in_plane_geometry(ti, s, 0.0)
    beta, u = ds.interpolate(ti, 0.0, to, po, wl)
    np.testing.assert_allclose(beta, beta_model(ti, s, wl), rtol=0, atol=1e-12)
    np.testing.assert_allclose(u, 0.01)
    for args, match in [((30, 0, 10, 180, 300.0), "wavelength 300 nm is outside"),
                        ((70, 0, 10, 180, 500.0), "outside the measured data"),
                        ((30, 0, 80, 180, 500.0), "outside the measured data"),
                        ((30, 45, 10, 225, 500.0), "sample rotation phi_i=45"),
                        ((30, 0, 10, 90, 500.0), "in the plane of incidence only")]:
        with pytest.raises(DatasetError, match=match):
            ds.interpolate(*args)


def test_interpolation_over_the_hemisphere():
    """Out-of-plane data: piecewise-linear over (theta_i, projected direction) is exact for linear data."""
    rows = []
    for ti in (20.0, 40.0):
        for to in (0.0, 20.0, 40.0, 60.0):
            for po in np.arange(0.0, 360.0, 30.0):
                x, y = np.sin(np.radians(to)) * np.cos(np.radians(po)), \
                    np.sin(np.radians(to)) * np.sin(np.radians(po))
                for w in (400.0, 500.0):
                    rows.append((ti, 0.0, to, po, w, 0.3 + 0.01 * ti + 0.2 * x - 0.1 * y + 0.001 * w,
                                 0.0, 1))
    table = pd.DataFrame(rows, columns=COLUMNS).drop_duplicates(subset=list(COLUMNS[:5]))
    table = table[~((table.theta_o == 0.0) & (table.phi_o != 0.0))]
    ds = make_dataset(table, meta())
    to, po = 30.0, 75.0
    x, y = np.sin(np.radians(to)) * np.cos(np.radians(po)), np.sin(np.radians(to)) * np.sin(np.radians(po))
    beta, _ = ds.interpolate(30.0, 0.0, to, po, 450.0)
    assert beta == pytest.approx(0.3 + 0.3 + 0.2 * x - 0.1 * y + 0.45, abs=1e-12)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=st.text(alphabet=st.sampled_from(list("0123456789.,-+eE naNinf\n\"x")), max_size=400))
def test_fuzzed_csv_gives_only_dataset_errors(tmp_path_factory, body):
    root = tmp_path_factory.mktemp("fuzz")
    (root / "meta.json").write_text(json.dumps({"schema": dsm.SCHEMA, "kind": "measured",
                                                "sample": {}}))
    (root / "radiance.csv").write_text(",".join(COLUMNS) + "\n" + body)
    try:
        ds = read_dataset(root)
    except DatasetError as exc:
        assert "radiance.csv" in str(exc) or "meta.json" in str(exc)
    else:  # whatever is accepted is valid
        assert len(ds) > 0 and np.isfinite(ds.table[list(COLUMNS)].to_numpy(dtype=float)).all()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(raw=st.binary(max_size=300), meta_raw=st.binary(max_size=120))
def test_fuzzed_bytes_give_only_dataset_errors(tmp_path_factory, raw, meta_raw):
    root = tmp_path_factory.mktemp("fuzzb")
    (root / "radiance.csv").write_bytes(raw)
    (root / "meta.json").write_bytes(meta_raw)
    with pytest.raises(DatasetError):
        read_dataset(root)


def test_written_files_are_shareable(tmp_path):
    """mkstemp creates 0600 files; a dataset gets the usual 0666 & ~umask permissions."""
    umask = os.umask(0o022)
    try:
        out = write_dataset(make_dataset(in_plane_table(incidences=(0.0,)), meta()), tmp_path / "d")
    finally:
        os.umask(umask)
    for name in ("radiance.csv", "meta.json"):
        assert (out / name).stat().st_mode & 0o777 == 0o644


# --- one clear line for hostile files ------------------------------------------------


def _set_meta(dataset_dir, edit):
    path = dataset_dir / "meta.json"
    m = json.loads(path.read_text())
    edit(m)
    path.write_text(json.dumps(m))


@pytest.mark.parametrize("edit, expected", [
    (lambda m: m.update(sample=["red"]), r"key 'sample' must be an object, not a list"),
    (lambda m: m.update(provenance="seed 1"), r"key 'provenance' must be an object, not a string"),
    (lambda m: m["sample"].update(name=7), r"key 'sample.name' must be a string, not a number"),
    (lambda m: m.update(wavelengths_nm="390..710"), r"key 'wavelengths_nm' must be a list"),
    (lambda m: m.update(wavelengths_nm=[390, "400"]), r"key 'wavelengths_nm\[1\]' must be a number"),
    (lambda m: m.update(files={"radiance.csv": ["abc"]}),
     r"key 'files.radiance.csv' must be an object, not a list"),
    (lambda m: m["files"]["radiance.csv"].update(sha256=12),
     r"key 'files.radiance.csv.sha256' must be a hexadecimal string"),
    (lambda m: m["provenance"].update(complete="no"),
     r"key 'provenance.complete' must be true or false, not a string"),
    (lambda m: m["provenance"].update(points_planned=True),
     r"key 'provenance.points_planned' must be a whole number, not true/false"),
    (lambda m: m.update(created=20260101), r"key 'created' must be an ISO-8601 date string"),
])
def test_meta_with_wrong_types_names_the_field(dataset_dir, edit, expected):
    _set_meta(dataset_dir, edit)
    with pytest.raises(DatasetError, match=expected) as info:
        read_dataset(dataset_dir)
    assert str(info.value).startswith(str(dataset_dir / "meta.json"))
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("depth, expected", [(10 ** 5, "nested too deeply"),
                                             (200, "nested deeper than 32 levels")])
def test_deeply_nested_meta_is_refused_without_recursion_error(dataset_dir, depth, expected):
    m = json.loads((dataset_dir / "meta.json").read_text())
    text = json.dumps(m)[:-1] + ', "deep": ' + "[" * depth + "]" * depth + "}"
    (dataset_dir / "meta.json").write_text(text)
    with pytest.raises(DatasetError, match=f"meta.json: {expected}"):
        read_dataset(dataset_dir)


@pytest.mark.parametrize("column, value, expected", [
    ("n", "1e20", r"column 'n': value 1e\+20 is out of range \(a count must be <= 2\^53"),
    ("u_beta", "1e308", r"column 'u_beta': value 1e\+308 is not a plausible standard uncertainty"),
    ("beta", "1e308", r"column 'beta': value 1e\+308 is not a plausible radiance coefficient"),
])
def test_out_of_range_values_are_refused(dataset_dir, column, value, expected):
    lines = (dataset_dir / "radiance.csv").read_text().splitlines()
    j = COLUMNS.index(column)
    cells = lines[3].split(",")
    cells[j] = value
    lines[3] = ",".join(cells)
    _rewrite_csv(dataset_dir, "\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match=r"radiance.csv, row 4, " + expected):
        read_dataset(dataset_dir)


def test_every_beta_1e308_is_refused_in_memory_too():
    table = in_plane_table(incidences=(0.0,), wavelengths=WL[:3])
    table["beta"] = 1e308
    table["u_beta"] = 0.0
    with pytest.raises(DatasetError, match="not a plausible radiance coefficient"):
        make_dataset(table, meta())
    # the largest counts that are accepted stay exact, never wrap to negative integers
    table["beta"], table["n"] = 0.5, float(dsm.N_MAX)
    assert int(make_dataset(table, meta()).table["n"].min()) == 2 ** 53


def test_a_fifo_or_a_symlink_loop_is_named_not_called_missing(dataset_dir):
    csv = dataset_dir / "radiance.csv"
    csv.unlink()
    os.mkfifo(csv)                  # reading it would block forever: it must not be opened
    with pytest.raises(DatasetError, match=r"radiance.csv: is a FIFO \(named pipe\), not a "):
        read_dataset(dataset_dir)
    csv.unlink()
    os.symlink(csv, csv)            # a link to itself: ELOOP
    with pytest.raises(DatasetError, match="radiance.csv: is a symbolic link that loops"):
        read_dataset(dataset_dir)
    csv.unlink()
    os.symlink(dataset_dir / "gone.csv", csv)
    with pytest.raises(DatasetError, match="symbolic link to a missing target"):
        read_dataset(dataset_dir)
    csv.unlink()
    csv.mkdir()
    with pytest.raises(DatasetError, match="radiance.csv: is a directory, not a regular file"):
        read_dataset(dataset_dir)



def test_a_looping_link_or_fifo_as_the_dataset_directory_is_named(tmp_path):
    loop = tmp_path / "run"
    os.symlink(loop, loop)
    with pytest.raises(DatasetError, match="run: is a symbolic link that loops"):
        read_dataset(loop)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(DatasetError, match=r"pipe: is a FIFO \(named pipe\), not a dataset dir"):
        read_dataset(fifo)
