"""Every measured figure of the README and the manual is rendered from the JSON its run wrote: the
committed tables must equal a fresh rendering, and each names its command and machine."""

from __future__ import annotations

import importlib.util
import json
import math
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _render():
    spec = importlib.util.spec_from_file_location("render_figures", ROOT / "docs" / "scripts" / "render_figures.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["render_figures"] = module
    spec.loader.exec_module(module)
    return module


def test_committed_figures_are_a_fresh_rendering():
    r = _render()
    stale = [str(p.relative_to(ROOT)) for p in r.pages() if r.render(p.read_text(encoding="utf-8"))
             != p.read_text(encoding="utf-8")]
    assert not stale, f"stale figures in {stale}: regenerate with `{r.REGENERATE}`"


def test_every_figure_is_used_and_names_its_command_and_machine():
    r = _render()
    text = "\n".join(p.read_text(encoding="utf-8") for p in r.pages())
    used = set(re.findall(r"<!-- BEGIN FIGURE: ([\w-]+) -->\n", text))
    assert set(r.FIGURES) <= used, f"figures never shown: {set(r.FIGURES) - used}"
    for name, make in r.FIGURES.items():
        out = make()
        assert "Produced by `" in out and ("CPU" in out or "logical CPUs" in out), name


def test_the_readme_cost_is_the_demo_json():
    r = _render()
    data = json.loads((r.DATA / "demo.json").read_text(encoding="utf-8"))
    block = re.search(r"<!-- BEGIN FIGURE: demo-cost -->\n(.*?)<!-- END FIGURE", (ROOT / "README.md").read_text(
        encoding="utf-8"), flags=re.S).group(1)
    minutes, seconds = divmod(round(data["data"]["wall_seconds"]), 60)
    assert f"{minutes} min {seconds:02d} s" in block
    assert data["command"] in block


def test_a_changed_json_shows_as_stale(tmp_path, monkeypatch):
    r = _render()
    data = json.loads((r.DATA / "driver.json").read_text(encoding="utf-8"))
    data["data"]["median_wall_s"] += 100.0
    (tmp_path / "driver.json").write_text(json.dumps(data), encoding="utf-8")
    for other in r.DATA.glob("*.json"):
        if other.name != "driver.json":
            (tmp_path / other.name).write_text(other.read_text(encoding="utf-8"), encoding="utf-8")
    monkeypatch.setattr(r, "DATA", tmp_path)
    page = ROOT / "docs" / "reference" / "figures.md"
    assert r.render(page.read_text(encoding="utf-8")) != page.read_text(encoding="utf-8")


def test_record_wraps_a_run_with_its_command_and_machine(tmp_path, monkeypatch):
    r = _render()
    monkeypatch.setattr(r, "DATA", tmp_path / "data")
    run = tmp_path / "run.json"
    run.write_text('{"x": 1}', encoding="utf-8")
    out = r.record("probe", run, "simulate bench --quick --out b")
    saved = json.loads(out.read_text(encoding="utf-8"))
    assert saved["command"] == "simulate bench --quick --out b" and saved["data"] == {"x": 1}
    assert saved["machine"]["cpus"] and saved["machine"]["cpu"]


def _measure():
    _render()
    spec = importlib.util.spec_from_file_location("measure_demo", ROOT / "docs" / "scripts" / "measure_demo.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_demo_measurement_times_every_command_of_the_makefile_recipe():
    m = _measure()
    commands = m.recipe()
    names = [m.step_name(c) for c in commands]
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    recipe_lines = re.search(r"^demo: .*?\n((?:\t.*\n)+)", makefile, flags=re.M).group(1).splitlines()
    assert len(commands) == len([line for line in recipe_lines if not line.lstrip("\t").startswith("@echo")])
    named = " + ".join(names).replace(" beside ", " + ").split(" + ")   # steps side by side: each named
    for method in ("classic", "summation", "mc"):
        assert f"simulate fit --method {method}" in named
    assert named.count("simulate fit --method classic") == 1 and "simulate fabric --method summation" in named
    assert names[0].startswith("gonio demo") and names[-1] == "compare report"


def test_a_line_of_two_steps_side_by_side_names_both():
    m = _measure()
    line = ("( .venv/bin/simulate fit a m --method mc --out x || [ $? -eq 3 ] ) & beside=$!; ( .venv/bin/simulate "
            "fit b m --method classic ) && ( .venv/bin/simulate fit c m --method summation ); s=$?; wait $beside")
    assert m.step_name(line) == ("simulate fit --method classic + simulate fit --method summation beside "
                                 "simulate fit --method mc")
    assert m.step_name(".venv/bin/gonio truth f --plan measured --out t --force") == "gonio truth"


def test_the_demo_measurement_sees_the_peak_memory_of_a_step_s_child_process():
    m = _measure()
    grow = "import numpy; a = numpy.ones(40_000_000); print(a.sum())"  # 320 MB in a grandchild of the step
    code, wall, cpu, peak_mb = m.timed(["sh", "-c", f"{sys.executable} -c '{grow}' > /dev/null"])
    assert code == 0 and wall > 0 and cpu > 0
    assert peak_mb > 300
    code, *_ = m.timed(["sh", "-c", "exit 3"])
    assert code == 3


def test_the_felt_demo_plan_table_is_its_json():
    r = _render()
    runs = json.loads((r.DATA / "felt-demo-plan.json").read_text(encoding="utf-8"))["data"]["runs"]
    block = re.search(r"<!-- BEGIN FIGURE: felt-demo-plan -->\n(.*?)<!-- END FIGURE", (
        ROOT / "docs" / "notes" / "felt-structure.md").read_text(encoding="utf-8"), flags=re.S).group(1)
    rows = [line for line in block.splitlines() if line.startswith("| ") and not line.startswith("| run")]
    assert len(rows) == len(runs)
    for row, run in zip(rows, runs, strict=True):
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[0] == run["label"] and cells[1].startswith(f"{run['nrmse']:.3f} (")
        assert [float(x) for x in cells[1].split("(")[1].rstrip(")").split(" / ")] == list(
            run["nrmse_by_incidence"].values())
        assert cells[3] == f"{run['k_Y']:.2f}"


def _record(tmp_path, name: str, data: dict) -> None:
    (tmp_path / f"{name}.json").write_text(json.dumps({
        "name": name, "command": f"python docs/scripts/felt_residual.py {name}",
        "machine": {"cpu": "probe", "cpus": 2, "system": "Linux x86_64", "python": "3.11"}, "data": data}),
        encoding="utf-8")


def _rows(table: str) -> list[list[str]]:
    return [[c.strip() for c in line.strip("|").split("|")] for line in table.splitlines()
            if line.startswith("| ")]


def test_the_felt_top_table_averages_each_pair_of_layers(tmp_path, monkeypatch):
    r = _render()
    _record(tmp_path, "felt-top", {"seeds": 2, "bin_um": 50.0, "profiles": {
        "green-felt-mc": [0.1, 0.3, 0.05, 0.0], "DIR/fuzz-0.1-300.toml": [0.0, 0.0, 0.2, 0.4]}})
    monkeypatch.setattr(r, "DATA", tmp_path)
    out = r.fig_felt_top()
    rows = _rows(out)
    assert rows[0] == ["felt", "0-100", "100-200"]
    assert rows[1] == ["`green-felt-mc`", "0.200", "0.025"]
    assert rows[2] == ["`fuzz-0.1-300`", "0", "0.300"]
    assert "`python docs/scripts/felt_residual.py felt-top`" in out and "streams 0 .. 1" in out


def test_the_felt_lambert_table_takes_each_albedo_s_column(tmp_path, monkeypatch):
    r = _render()
    rise = {"all 0": {"ratio": [0.81, 0.93], "se": [0.004, 0.005]},
            "all 30": {"ratio": [0.69, 0.87], "se": [0.006, 0.005]},
            "single 0": {"ratio": [0.79, 0.79], "se": [0.004, 0.004]},
            "single 30": {"ratio": [0.64, 0.64], "se": [0.009, 0.009]}}
    _record(tmp_path, "felt-lambert", {"albedos": [0.5, 1.0], "rise": {"DIR/fuzz-0.3-1000.toml": rise}})
    monkeypatch.setattr(r, "DATA", tmp_path)
    out = r.fig_felt_lambert()
    rows = _rows(out)
    assert rows[0] == ["felt", "single scattering at 0 / 30 deg", "all orders, albedo 0.5", "all orders, albedo 1"]
    assert rows[1] == ["`fuzz-0.3-1000`", "0.790 / 0.640", "0.810 / 0.690", "0.930 / 0.870"]
    assert "standard error 0.004-0.009" in out


def test_the_loose_top_bias_table_is_its_json():
    r = _render()
    runs = json.loads((r.DATA / "felt-residual-fuzz.json").read_text(encoding="utf-8"))["data"]["runs"]
    block = re.search(r"<!-- BEGIN FIGURE: felt-residual-fuzz -->\n(.*?)<!-- END FIGURE", (
        ROOT / "docs" / "notes" / "felt-structure.md").read_text(encoding="utf-8"), flags=re.S).group(1)
    second = block.split("\n\n")[1]
    rows = _rows(second)[1:]
    assert len(rows) == len(runs)
    for row, (run, res) in zip(rows, runs.items(), strict=True):
        assert row[0] == f"`{run.rsplit('/', 1)[-1]}`"
        assert abs(float(row[1]) - res["nrmse_best_scale"]) <= 5e-4
        biases = [float(x) for x in row[2].split(" / ")]
        assert all(abs(b - res["by_region"][k]["bias_rel"]) <= 5e-4 for b, k in zip(biases, ("back", "near", "forward"), strict=True))


def test_the_fiber_phase_tables_take_the_ratios_and_the_lambertian_felt_s_factor(tmp_path, monkeypatch):
    r = _render()
    views = [-70.0, -30.0, 0.0, 30.0, 70.0]
    band = {"curve": [0.2, 0.4, 1.0, 0.4, 0.2], "volume_share": [0.5] * 5, "ratio": 0.5, "se": 0.01,
            "volume_albedo": 0.6, "upper_share": 0.2}
    phase = {"views_deg": views, "photons_per_row": 100, "tables": 2, "azimuths": 8, "surface_albedo": 0.05,
             "bands": {"390-500 nm": {**band, "ratio": 0.4}, "all": band}}
    felt = {k: {"bands": {"390-500 nm": {"ratio": 0.7, "se": 0.02}, "all": {"ratio": 0.8, "se": 0.01}}}
            for k in ("single", "all")}
    _record(tmp_path, "fiber-phase", {"lambert": {"curve": [0.1, 0.5, 1.0, 0.5, 0.1], "ratio": 0.25,
                                                  "upper_share": 0.9},
                                      "configs": {"green-felt-mc": phase}, "felt": {"green-felt-mc": felt},
                                      "factor_plane": 1.7, "factor_isotropic": 1.4})
    _record(tmp_path, "felt-lambert", {"albedos": [0.2], "rise": {"green-felt-mc": {"single 0": {
        "ratio": [0.5], "se": [0.01]}}}})
    monkeypatch.setattr(r, "DATA", tmp_path)
    out = r.fig_fiber_phase()
    tables = [_rows(t) for t in out.split("\n\n") if t.startswith("| ")]
    assert tables[0][1] == ["opaque Lambertian", "0.250", "0.250", "-", "-", "0.90"]
    assert tables[0][2] == ["`green-felt-mc`", "0.400", "0.500 ± 0.010", "0.600", "0.050", "0.20"]
    assert tables[1][0] == ["fibre", "0 (180)", "30 (150)", "70 (110)"]
    assert tables[1][2] == ["`green-felt-mc` 390-500 nm", "1.000", "0.400", "0.200"]
    # the Lambertian felt's factor: its single scattering 0.5 over the Lambertian fibre's 0.25
    assert tables[2][0][5] == "× 2.00 (the Lambertian felt's)"
    assert tables[2][2] == ["`green-felt-mc`", "all", "0.500", "0.700", "0.850", "1.000", "0.800 ± 0.010",
                            "0.800 ± 0.010"]


def test_the_two_field_table_ranks_the_fibres_by_their_distance_from_what_the_file_asks(tmp_path, monkeypatch):
    r = _render()
    rise = {"0": 1.54 * 0.6, "30": 1.75 * 0.8, "60": 1.75 * 3.0}
    _record(tmp_path, "felt-residual", {"runs": {"DIR/preset": {"forward_rise": {
        t: {"measured": v, "simulated": 1.0} for t, v in rise.items()}}}})

    def normal(ratio: float) -> dict:
        return {"photons_per_row": 100, "tables": 2, "bands": {
            "all": {"ratio": ratio, "se": 0.01}, "510-580 nm": {"ratio": ratio, "se": 0.01, "volume_albedo": 0.5}}}

    _record(tmp_path, "fiber-phase-twofield", {
        "configs": {"DIR/a.toml": normal(0.6), "DIR/b.toml": normal(0.3)},
        "oblique": {"DIR/a.toml": {"incidences_deg": [30.0, 60.0], "bands": {"all": {"ratio": [0.8, 1.5],
                                                                                      "se": [0.02, 0.03]}}},
                    "DIR/b.toml": {"incidences_deg": [30.0, 60.0], "bands": {"all": {"ratio": [0.4, 3.0],
                                                                                      "se": [0.02, 0.03]}}}}})
    monkeypatch.setattr(r, "DATA", tmp_path)
    rows = _rows(r.fig_fiber_phase_twofield())
    # at the normal the file's 0.924 over 1.75 and 1.54: 0.528-0.600; at 30 / 60 deg over 1.75: 0.8, 3.0
    assert rows[1] == ["the file asks", "0.53-0.60 / 0.80 / 3.00", "-", "-", "-"]
    # a: inside the range, on the value at 30 deg, half the value at 60 deg: ln(2)^2
    assert rows[2][0] == "`a`" and rows[2][1] == "0.600 ± 0.010 / 0.800 ± 0.020 / 1.500 ± 0.030"
    assert rows[2][3] == f"{0.6931471805599453 ** 2:.3f}" and rows[2][4] == "1"
    # b: below the range's low end 0.528 at the normal, half at 30 deg, on the value at 60 deg
    expected = (math.log(0.3 / (0.924 / 1.75))) ** 2 + math.log(0.5) ** 2
    assert rows[3][3] == f"{expected:.3f}" and rows[3][4] == "2"


def test_the_two_field_fit_table_names_each_run_with_its_least_squares_nrmse_and_biases(tmp_path, monkeypatch):
    r = _render()
    region = {"n": 1, "share": 0.5, "bias_rel": 0.25, "nrmse_without": 0.1}
    run = {"nrmse": 0.2, "nrmse_best_scale": 0.15, "by_incidence": {"0": {"nrmse_own": 0.2, "share": 1.0}},
           "by_region": {"back": {**region, "bias_rel": -0.125}, "near": region, "forward": {**region, "bias_rel": 0.5},
                         "grazing": {"n": 0}, "ring-6": {"n": 0}, "ring-30": {"n": 0}},
           "forward_rise": {"0": {"measured": 0.99, "simulated": 0.8}},
           "colour": {"dh": 0.001, "ds": -0.002, "k_Y": 2.0}}
    _record(tmp_path, "felt-residual-twofield", {"runs": {"DIR/fit-around-1.0-rms-0.34-s1": run}})
    monkeypatch.setattr(r, "DATA", tmp_path)
    out = r.fig_felt_residual_twofield()
    tables = [_rows(t) for t in out.split("\n\n") if t.startswith("| ")]
    assert tables[0][2] == ["`fit-around-1.0-rms-0.34-s1`", "0.200 (0.200)", "50 % / 50 % / 50 %", "0.80",
                            "+0.001 / -0.002 / 2.00"]
    assert tables[1][1] == ["`fit-around-1.0-rms-0.34-s1`", "0.150", "-0.125 / +0.250 / +0.500"]
    assert "--free dye,rms_slope,surface.transmission_rms_slope_around" in out
