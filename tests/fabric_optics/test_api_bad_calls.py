"""A wide table of bad calls of the Python interface: every one raises a typed error before any work.

For every function of ``fabric_optics.api.__all__`` (importing a measurement and writing a report included) but ``fit`` (the fit's own tests cover it) and
``prepare_fit``/``FitJob``: wrong types (a bool for an int, '10' for a number, 1.5 for a count, lists,
None), NaN and infinities, negatives, sizes that would allocate gigabytes, costs of years, outputs
that cannot be written. Each call must raise an :class:`InputError`, :class:`OutputExistsError` or
:class:`FileSystemError` (never :class:`InternalError`, never an untyped exception), with no
``MemoryError`` or ``RecursionError`` behind it, within a few seconds (pytest-timeout), and write
nothing.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

import fabric_optics as fo
from fabric_optics import api

ROOT = Path(__file__).resolve().parents[2]
MEASURED = ROOT / "fixtures" / "analytic" / "measured_red"
SIM = ROOT / "fixtures" / "analytic" / "sim_scaled"
FELT = ROOT / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"
NAN, INF = math.nan, math.inf

#: bad values of each kind of argument
COUNT = [True, "10", 1.5, 10.0, [1], NAN]
FLAG = ["yes", 1, None]
SEED = [-1, 2**31, 1.5, "1", True, NAN]
THREADS = [-1, 10**6, 1.5, "2", True]
REL_ERR = [0, 0.0, 1, -0.1, NAN, INF, "0.1", True]
THRESHOLD = [-1, NAN, INF, "0.1", True, None]
PATHS = [1, None, True, "", "a\0b", ["x"], b"red-cotton"]
OUT = PATHS + ["/proc/fabric-optics-test/x"]


def _cases():
    c = []

    def add(fn, base, arg, values):
        for v in values:
            c.append(pytest.param(fn, base, arg, v, id=f"{fn}-{arg}={v!r}"[:90]))

    add("load_config", {}, "config", PATHS + [3.5, "no-such-config"])
    add("load_plan", {}, "plan", PATHS + [3.5, "no-such-plan"])
    add("read_dataset", {}, "path", PATHS + ["/no/such/dataset", str(ROOT / "fixtures")])
    w = {"dataset": "MEASURED_DATASET", "path": "TMP/out"}
    add("write_dataset", w, "dataset", [None, "x", 1, str(MEASURED)])
    add("write_dataset", w, "path", OUT)
    add("write_dataset", w, "force", FLAG)
    add("truth", {"plan": "quick"}, "sample", [1, None, "", "no-such-sample", "lambert:2", "lambert:nan",
                                               "lambert:-1", ["lambert:0.5"]])
    add("truth", {"sample": "lambert:0.5"}, "plan", [1, "no-such-plan", ["quick"]])
    s = {"config": "red-cotton", "plan": "quick", "method": "classic"}
    add("simulate", s, "config", [1, None, "no-such-config"])
    add("simulate", s, "plan", [1, "no-such-plan"])
    add("simulate", s, "method", ["exact", 1, None])
    add("simulate", s, "target_rel_err", REL_ERR)
    add("simulate", {**s, "method": "mc"}, "target_rel_err", [1e-6, 1e-7])    # years of Monte Carlo
    add("simulate", s, "seed", SEED)
    add("simulate", s, "threads", THREADS)
    add("simulate", s, "max_photons", [0, -5, 10**16] + COUNT)
    add("simulate", s, "measurable_only", FLAG)
    add("simulate", s, "progress", ["no", 0])
    add("simulate", s, "max_seconds", [-1, NAN, INF, "1", True])
    m = {"measured": str(MEASURED), "simulated": str(SIM)}
    add("compare", m, "measured", [1, None, "/no/such/dataset"])
    add("compare", m, "simulated", [[], 1, None, ["/no/such/dataset"]])
    add("compare", m, "window_deg", [0, -1, NAN, 91, "5", True])
    add("compare", m, "illuminant", [1, None, "no-such-illuminant"])
    k = {"comparison": "COMPARISON"}
    add("check", k, "comparison", [None, 1, "x"])
    add("check", k, "name", [1, "no-such-simulation"])
    for arg in ("max_nrmse", "max_hue_diff", "max_sat_diff", "max_level_ratio"):
        add("check", k, arg, THRESHOLD)
    mo = {"out": "TMP/mock"}
    add("measure_on_mock", mo, "out", OUT)
    add("measure_on_mock", mo, "sample", [1, None, "no-such-sample", "lambert:7"])
    add("measure_on_mock", mo, "plan", [1, "no-such-plan"])
    add("measure_on_mock", mo, "seed", [-1, 1.5, "1", True])
    add("measure_on_mock", mo, "force", ["yes"])
    add("measure_on_mock", mo, "progress", [1])
    e = {"source": "red-cotton", "path": "TMP/x.bsdf"}
    add("export_bsdf", e, "source", [1, None, "no-such-config"])
    add("export_bsdf", e, "path", OUT)
    add("export_bsdf", e, "method", ["exact", 1])
    add("export_bsdf", e, "wavelengths_nm", ["450", [NAN], [500.0, 400.0], list(range(400, 100_400)), [1e9],
                                             [], 550.0])
    add("export_bsdf", e, "rgb", ["yes", 1])
    add("export_bsdf", e, "resolution", [3, 257, 10**9] + COUNT)
    add("export_bsdf", e, "incidences", [1, 65, "16", 16.5])
    add("export_bsdf", e, "target_rel_err", [0, 2, NAN, "0.1"])
    add("export_bsdf", {**e, "method": "mc"}, "target_rel_err", [1e-7])
    add("export_bsdf", e, "seed", [-1, "0", 2**40])
    add("export_bsdf", e, "threads", [-1, 1.5])
    add("export_bsdf", e, "max_photons", [0, "1"])
    add("export_bsdf", e, "check_pairs", [10**9, -1, 1.5, "10", True])
    add("export_bsdf", e, "anisotropic", [3, -1, "4", True, 4.0])
    add("export_bsdf", e, "azimuths", [10**6, 2, -1, "5", 5.5])
    add("export_bsdf", e, "description", [1, "x" * 100_000])
    add("export_bsdf", e, "provenance", [[1], "x", 1])
    add("export_bsdf", e, "force", ["yes"])
    add("export_bsdf", e, "progress", [1])
    i = {"path": str(FELT)}
    add("import_measurement", i, "path", PATHS[:1] + PATHS[2:] + [[], ["x"] * 1001, "/no/such/file.bsdf"])
    add("import_measurement", i, "format", ["csv", 1, True])
    add("import_measurement", {**i, "format": "pgii"}, "scale", [0, -1.0, NAN, INF, "1", True])
    add("import_measurement", i, "white_reflectance", [0, 1.5, NAN, "0.99", None])
    add("import_measurement", i, "plan", [1, "no-such-plan"])
    add("import_measurement", i, "out", OUT[:1] + OUT[2:])
    add("import_measurement", i, "force", FLAG)
    r = {"measured": str(MEASURED), "out": "TMP/report"}
    add("write_report", r, "measured", PATHS + ["/no/such/dataset"])
    add("write_report", r, "out", OUT)
    add("write_report", r, "fits", ["fit-folder", 1, [1]])
    add("write_report", r, "seed_sample", [1, "/no/such/dataset"])
    add("write_report", r, "renders", [1, "/no/such/renders"])
    add("write_report", r, "svg", FLAG)
    add("write_report", r, "window_deg", [0, -1, NAN, "5", 91])
    add("write_report", r, "illuminant", [1, "no-such-illuminant"])
    return c


CASES = _cases()


def test_the_table_is_wide_and_covers_every_public_function():
    assert len(CASES) >= 100
    covered = {p.values[0] for p in CASES}
    functions = {n for n in api.__all__ if callable(getattr(api, n, None)) and not isinstance(getattr(api, n), type)}
    assert functions - covered == {"fit", "prepare_fit"}


@pytest.fixture(scope="module")
def comparison():
    return fo.compare(MEASURED, SIM)


@pytest.fixture(scope="module")
def measured_dataset():
    return fo.read_dataset(MEASURED)


@pytest.mark.timeout(30)
@pytest.mark.parametrize("fn,base,arg,value", CASES)
def test_a_bad_call_raises_a_typed_error_before_any_work(fn, base, arg, value, tmp_path, comparison,
                                                          measured_dataset):
    def resolve(v):
        if v == "COMPARISON":
            return comparison
        if v == "MEASURED_DATASET":
            return measured_dataset
        if isinstance(v, str) and v.startswith("TMP/"):
            return tmp_path / v[4:]
        return v
    kwargs = {a: resolve(v) for a, v in base.items()}
    kwargs[arg] = value
    with pytest.raises(fo.ToolkitError) as info:
        getattr(fo, fn)(**kwargs)
    exc = info.value
    assert isinstance(exc, (fo.InputError, fo.OutputExistsError, fo.FileSystemError)), repr(exc)
    assert not isinstance(exc.__cause__, (MemoryError, RecursionError)), repr(exc.__cause__)
    assert str(exc).strip() and "\n" not in str(exc).strip()
    assert list(tmp_path.iterdir()) == []             # nothing written, no lock file left
