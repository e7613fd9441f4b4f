"""Crafted inputs: each is one line naming the file or field, exit 2, bounded memory and time.

Every case here used to allocate gigabytes (or raise a traceback) before any check; the bounds
are :data:`simulate.geometry.weave.MAX_TRIANGLES`, :data:`simulate.geometry.weave.MAX_WEAVE_CELLS`,
:data:`simulate.geometry.wif.MAX_WIF_BYTES` and the others named in each test.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from fabric_optics.cli.simulate import main
from simulate.geometry.mesh import mesh
from simulate.geometry.weave import MAX_TRIANGLES, MAX_WEAVE_CELLS, Weave, WeaveError, preset, triangle_count
from simulate.geometry.wif import MAX_WIF_BYTES, read_wif

PRESETS_PLAIN = [[1, 0], [0, 1]]

BASE = """
[fiber]
radius_um = 8.0
n_host = 1.557
[medium]
mu_s = 1.0
mu_a = 0.01
g = 0.8
[surface]
rms_slope = 0.3
"""


def _one_line_exit_2(capsys, argv: list[str], *needles: str) -> str:
    try:
        code = main(argv)
    except SystemExit as exc:      # an option's value refused by argparse
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    return err


def _wif(tmp_path: Path, weaving: str = "Shafts=2\nTreadles=2", warp: str = "Threads=2", weft: str = "Threads=2",
         threading: str = "1=1\n2=2", extra: str = "[TIEUP]\n1=1\n2=2\n[TREADLING]\n1=1\n2=2\n") -> Path:
    path = tmp_path / "crafted.wif"
    path.write_text(f"[WIF]\nVersion=1.1\n[WEAVING]\n{weaving}\n[WARP]\n{warp}\n[WEFT]\n{weft}\n"
                    f"[THREADING]\n{threading}\n{extra}")
    return path


# ------------------------------------------------------------------------------------------
# item 1: WIF and [weave] sizes


def test_wif_huge_shaft_count_allocates_nothing(tmp_path):
    # Shafts=1e10 used to build the set of every shaft (2.5 GB); it only bounds the numbers named.
    # A sinking shed needs "the other shafts": the drawdown must still be the plain weave's complement.
    rising = read_wif(_wif(tmp_path, weaving="Shafts=10000000000\nTreadles=2"))
    assert rising.tolist() == [[1, 0], [0, 1]]
    sinking = read_wif(_wif(tmp_path, weaving="Shafts=10000000000\nTreadles=2\nRising Shed=false"))
    assert sinking.tolist() == [[0, 1], [1, 0]]


@pytest.mark.parametrize("warp, weft", [("Threads=1000000000", "Threads=2"), ("Threads=30000", "Threads=30000")])
def test_wif_thread_counts_bounded_before_allocation(tmp_path, warp, weft):
    with pytest.raises(WeaveError) as info:
        read_wif(_wif(tmp_path, warp=warp, weft=weft))
    message = str(info.value)
    assert "crafted.wif" in message and "crossings" in message and f"{MAX_WEAVE_CELLS:,}" in message


def test_wif_undeclared_thread_number_is_bounded(tmp_path):
    # no [WARP] Threads: the count is the largest thread number named, here 1e9
    path = _wif(tmp_path, warp="Units=centimeters", threading="1=1\n1000000000=2")
    with pytest.raises(WeaveError, match="crossings"):
        read_wif(path)


def test_wif_largest_accepted_drawdown_reads(tmp_path):
    # exactly at the bound: MAX_WEAVE_CELLS = 2 x n picks is read (and is then too big to mesh finely)
    n = MAX_WEAVE_CELLS // 2
    treadling = "\n".join(f"{i}={1 + i % 2}" for i in range(1, n + 1))
    m = read_wif(_wif(tmp_path, weft=f"Threads={n}", extra=f"[TIEUP]\n1=1\n2=2\n[TREADLING]\n{treadling}\n"))
    assert m.shape == (2, n)
    assert m[:, 0].tolist() == [0, 1] and m[:, 1].tolist() == [1, 0]   # pick 1: treadle 2 lifts shaft 2


def test_wif_file_size_and_kind(tmp_path):
    big = tmp_path / "big.wif"
    with open(big, "wb") as f:          # sparse: no disk used
        f.truncate(MAX_WIF_BYTES + 1)
    with pytest.raises(WeaveError, match="16 MiB"):
        read_wif(big)
    fifo = tmp_path / "pipe.wif"
    os.mkfifo(fifo)
    with pytest.raises(WeaveError, match="not a regular file"):   # would block on open/read
        read_wif(fifo)


def test_weave_mesh_bound_counts_triangles_exactly():
    w = preset("twill", points_per_span=3, sides=5)
    assert len(mesh(w).faces) == triangle_count(w.n_warp, w.n_weft, 3, 5)


def test_weave_refuses_mesh_over_the_bound_before_building():
    # (documented limits 100000 each) -> 4 x 1e5 x 1e5 x 2 x 2 = 1.6e11 triangles (149 GiB)
    with pytest.raises(WeaveError) as info:
        preset("plain", points_per_span=100_000, sides=100_000)
    message = str(info.value)
    assert "160,000,000,000 triangles" in message and f"{MAX_TRIANGLES:,}" in message
    # one step under the bound is a weave
    sides = MAX_TRIANGLES // (4 * 4 * 2 * 2)
    assert Weave([[1, 0], [0, 1]], points_per_span=4, sides=sides).sides == sides
    with pytest.raises(WeaveError, match="triangles"):
        Weave([[1, 0], [0, 1]], points_per_span=4, sides=sides + 1)


def test_weave_400_by_400_matrix_refused_by_its_mesh():
    m = np.tile(np.array(PRESETS_PLAIN), (200, 200))       # a valid 400 x 400 weave
    from simulate.geometry.weave import DEFAULT_POINTS_PER_SPAN, DEFAULT_SIDES

    # 4 sides points_per_span n_warp n_weft triangles with the default tube
    expected = 4 * DEFAULT_SIDES * DEFAULT_POINTS_PER_SPAN * 400 * 400
    assert expected > MAX_TRIANGLES
    with pytest.raises(WeaveError, match=f"{expected:,} triangles"):
        Weave(m)
    with pytest.raises(WeaveError, match="crossings"):   # past the cell bound: refused before listing it
        Weave(np.tile(m, (2, 2)))


def test_cli_weave_config_too_large_one_line(tmp_path, capsys):
    cfg = tmp_path / "huge.toml"
    cfg.write_text(BASE + "[weave]\npoints_per_span = 100000\nsides = 100000\n")
    out = tmp_path / "m.ply"
    _one_line_exit_2(capsys, ["weave", str(cfg), "--out", str(out)], "huge.toml", "triangles")
    assert not out.exists()


def test_cli_weave_wif_too_large_one_line(tmp_path, capsys):
    wif = _wif(tmp_path, warp="Threads=1000000000")
    cfg = tmp_path / "w.toml"
    cfg.write_text(BASE + f'[weave]\nwif = "{wif.name}"\n')
    _one_line_exit_2(capsys, ["weave", str(cfg), "--out", str(tmp_path / "m.ply")], "crafted.wif", "crossings")


def test_weave_export_failure_leaves_no_truncated_mesh(tmp_path, monkeypatch, capsys):
    import trimesh

    cfg = tmp_path / "c.toml"
    cfg.write_text(BASE)
    out = tmp_path / "m.ply"
    out.write_bytes(b"the user's previous mesh")

    def full_disk(self, file_obj=None, file_type=None, **kw):
        file_obj.write(b"ply\nformat binary_little_endian 1.0\n")    # a partial write, then ENOSPC
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(trimesh.Trimesh, "export", full_disk)
    _one_line_exit_2(capsys, ["weave", str(cfg), "--out", str(out), "--force"], "m.ply", "No space left")
    assert out.read_bytes() == b"the user's previous mesh"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml", "m.ply"]   # no temporary file left


def test_weave_export_interrupted_leaves_nothing(tmp_path, monkeypatch):
    import trimesh

    def interrupted(self, file_obj=None, file_type=None, **kw):
        file_obj.write(b"ply\n")
        raise KeyboardInterrupt

    monkeypatch.setattr(trimesh.Trimesh, "export", interrupted)
    with pytest.raises(KeyboardInterrupt):
        mesh(preset("plain", points_per_span=2, sides=3)).export(tmp_path / "m.obj")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------
# item 2: tracebacks


def _rgb_measurement(folder: Path) -> Path:
    import pandas as pd

    from gonio.data import make_dataset, new_meta, write_dataset

    rows = [dict(theta_i=t, phi_i=0.0, theta_o=30.0, phi_o=180.0, channel=c, beta=0.3, u_beta=0.01, n=1)
            for t in (0.0, 45.0) for c in "RGB"]
    write_dataset(make_dataset(pd.DataFrame(rows), new_meta("measured", {"name": "rgb"})), folder / "rgb")
    return folder / "rgb"


@pytest.mark.parametrize("wavelengths, needle", [
    ("10", "wavelengths must be in [200, 2500] nm, got 10..10"),
    ("1,nan", "wavelengths must be finite numbers, got '1,nan'"),
    ("500,nan", "wavelengths must be finite numbers, got '500,nan'"),
    ("600,500", "list the wavelengths increasing, each once, got '600,500'"),
    ("500,500", "list the wavelengths increasing, each once, got '500,500'"),
])
def test_fit_wavelengths_checked_before_any_work(tmp_path, capsys, wavelengths, needle):
    measured = _rgb_measurement(tmp_path)
    out = tmp_path / "fit"
    _one_line_exit_2(capsys, ["fit", "red-cotton", str(measured), "--free", "rms_slope", "--wavelengths", wavelengths,
                              "--out", str(out)], "argument --wavelengths: ", needle)
    assert not out.exists()


@pytest.mark.parametrize("step", ["0.0009765625", "9.094947017729282e-13"])   # 2^-10, 2^-40: both divide 90
def test_fiber_table_grid_bounded_before_allocation(tmp_path, capsys, step):
    out = tmp_path / "table"
    _one_line_exit_2(capsys, ["fiber", "red-cotton", "--out", str(out), "--step-deg", step],
                     "--step-deg", "direction pairs", "coarser step")
    assert not out.exists()


@pytest.mark.parametrize("nest", ["[" * 5000 + "]" * 5000, "{a = " * 5000 + "1" + "}" * 5000])
def test_config_nested_5000_deep_is_one_line(tmp_path, capsys, nest):
    cfg = tmp_path / "deep.toml"
    cfg.write_text(BASE + f"[weave]\nmatrix = {nest}\n")
    _one_line_exit_2(capsys, ["weave", str(cfg), "--out", str(tmp_path / "m.ply")], "deep.toml", "nested too deeply")


# ------------------------------------------------------------------------------------------
# item 3: accepted and never finishing -> refused from the estimate, before any work


def _red_cotton_with(tmp_path: Path, old: str, new: str) -> Path:
    from simulate.config import resolve_config_path

    text = resolve_config_path("red-cotton").read_text()
    assert old in text
    path = tmp_path / "variant.toml"
    path.write_text(text.replace(old, new))
    return path


@pytest.fixture
def no_fiber_work(monkeypatch):
    """Fails the test if any fiber Monte Carlo or Mie phase function starts."""
    from simulate import fiber as fiber_mod
    from simulate.optics import mie

    def forbidden(*a, **k):
        raise AssertionError("work started before the cost check")

    for name in ("volume_brdf", "normal_albedo"):
        monkeypatch.setattr(fiber_mod, name, forbidden)
    monkeypatch.setattr(mie, "ensemble_phase_function", forbidden)


def test_particles_larger_than_the_fiber_refused(tmp_path, capsys, no_fiber_work):
    cfg = _red_cotton_with(tmp_path, "median_radius_um = 0.10", "median_radius_um = 1e3")
    _one_line_exit_2(capsys, ["fabric", str(cfg), "--method", "summation", "--out", str(tmp_path / "o")],
                     "variant.toml", "particles.size.median_radius_um", "fiber.radius_um")


def test_huge_particles_inside_a_huge_fiber_refused_for_their_mie_cost(tmp_path, capsys, no_fiber_work):
    cfg = _red_cotton_with(tmp_path, "median_radius_um = 0.10", "median_radius_um = 1e3")
    cfg.write_text(cfg.read_text().replace("radius_um = 10.0", "radius_um = 5000.0", 1))
    _one_line_exit_2(capsys, ["fabric", str(cfg), "--method", "summation", "--out", str(tmp_path / "o")],
                     "variant.toml", "Mie", "smaller particles")


def test_number_density_beyond_packing_refused(tmp_path, capsys, no_fiber_work):
    cfg = _red_cotton_with(tmp_path, "volume_fraction = 0.05", "number_density_per_um3 = 1e14")
    _one_line_exit_2(capsys, ["fabric", str(cfg), "--method", "classic", "--out", str(tmp_path / "o")],
                     "variant.toml", "number_density_per_um3 = 1e+14", "cannot fit")


def test_dense_medium_refused_with_its_estimate(tmp_path, capsys, no_fiber_work):
    # 1e4 scattering events per um in a 16 um fiber: every photon runs into the 1e6-event cap
    cfg = tmp_path / "dense.toml"
    cfg.write_text(BASE.replace("mu_s = 1.0", "mu_s = 1e4"))
    err = _one_line_exit_2(capsys, ["fabric", str(cfg), "--method", "classic", "--out", str(tmp_path / "o")],
                           "dense.toml", "estimated cost", "1e+06 events each")
    assert "--max-photons" in err


def test_tiny_target_refused_with_its_estimate(tmp_path, capsys, no_fiber_work):
    # red-cotton leaves target_rel_err at its default (0.01), so the variant adds a [method] table
    cfg = _red_cotton_with(tmp_path, "\n[structure]", "\n[method]\ntarget_rel_err = 1e-9\n\n[structure]")
    _one_line_exit_2(capsys, ["fabric", str(cfg), "--method", "summation", "--out", str(tmp_path / "o")],
                     "estimated cost", "target_rel_err 1e-09", "years")
    # the flag too, for every command that runs the fiber Monte Carlo
    _one_line_exit_2(capsys, ["fiber", "red-cotton", "--target-rel-err", "1e-9", "--out", str(tmp_path / "t")],
                     "estimated cost")


def test_sweep_grid_refused_before_building_configs(tmp_path, capsys, monkeypatch):
    from fabric_optics.sweep import spec as sweep_spec

    built = []
    real = sweep_spec.parse_config
    monkeypatch.setattr(sweep_spec, "parse_config", lambda *a, **k: built.append(1) or real(*a, **k))
    values = ",".join(f"{0.01 + 0.0001 * k:.4f}" for k in range(1000))
    radii = ",".join(f"{5 + 0.001 * k:.3f}" for k in range(1000))
    _one_line_exit_2(capsys, ["sweep", "red-cotton", "--param", f"rms_slope={values}", "--param", f"radius={radii}",
                              "--out", str(tmp_path / "s")], "1000 x 1000 = 1,000,000 points", "at most 10,000")
    assert built == [] and not (tmp_path / "s").exists()


# ------------------------------------------------------------------------------------------
# item 4: nonsense accepted


@pytest.mark.parametrize("rel", ["../..", "points/../..", "/etc", "points/a/b", "points/..", "tasks/x", 7])
def test_sweep_point_dirs_must_stay_inside(tmp_path, rel):
    from fabric_optics.sweep.spec import SweepError, point_dir

    with pytest.raises(SweepError, match="point dir"):
        point_dir(tmp_path, rel)


def test_sweep_point_dir_symlink_out_refused(tmp_path):
    from fabric_optics.sweep.spec import SweepError, point_dir

    (tmp_path / "points").mkdir()
    (tmp_path / "points" / "x=1").symlink_to(tmp_path.parent)
    with pytest.raises(SweepError, match="outside"):
        point_dir(tmp_path, "points/x=1")
    assert point_dir(tmp_path, "points/x=2") == tmp_path / "points" / "x=2"


def test_compare_refuses_a_sweep_json_leading_outside(tmp_path):
    import json

    from compare.errors import CompareError
    from compare.sweep import read_sweep

    doc = {"parameters": [{"name": "radius"}], "points": [{"dir": "../..", "label": "radius=1", "values": {"radius": 1}}]}
    (tmp_path / "sweep.json").write_text(json.dumps(doc))
    with pytest.raises(CompareError, match="point dir '../..'"):
        read_sweep(tmp_path)
    doc["points"][0]["dir"] = "points/radius=1"
    (tmp_path / "sweep.json").write_text(json.dumps(doc))
    assert read_sweep(tmp_path)["points"][0]["dir"] == "points/radius=1"


def test_threads_zero_means_all_numba_allows(monkeypatch, capsys):
    import json

    import numba

    from simulate.products import all_threads

    monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", 1)     # as NUMBA_NUM_THREADS=1 in the environment
    assert all_threads(0) == all_threads(None) == 1 and all_threads(3) == 3
    # --threads 0 is accepted where the config's threads = 0 is
    assert main(["slab", "--mua", "0.1", "--mus", "1", "--thickness", "1", "--photons", "2000", "--threads", "0",
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["photons"] == 2000


def test_mc_with_config_threads_zero_uses_numba_limit(monkeypatch):
    """NUMBA_NUM_THREADS=1 and threads = 0 used to pass os.cpu_count() (2) and be refused."""
    import numba

    from simulate import raytrace
    from simulate.config import load_config
    from simulate.products import Geometries, RunSettings, evaluate

    seen = {}

    def fake_fabric_beta(mesh, fiber, w_i, w_o, wl, **kw):
        seen.update(kw)
        raise RuntimeError("stop here")

    monkeypatch.setattr(numba.config, "NUMBA_NUM_THREADS", 1)
    monkeypatch.setattr(raytrace, "fabric_beta", fake_fabric_beta)
    config = load_config("red-cotton")
    assert config.threads is None              # the shipped config leaves threads at its default, 0
    g = Geometries(np.array([0.0]), np.array([0.0]), np.array([30.0]), np.array([180.0]))
    with pytest.raises(RuntimeError, match="stop here"):
        evaluate("mc", config, config.fiber(np.array([550.0])), g, np.array([550.0]),
                 RunSettings(target=0.1, seed=0, threads=config.threads))
    assert seen["threads"] == 1


@pytest.mark.parametrize("table, needle", [
    ("[surface]\nrms_slop = 0.3\n", "surface.rms_slop is not a known field (did you mean rms_slope?)"),
    ("[surface]\nrms_slope = 0.3\nrms_slopee = 1\n", "surface.rms_slopee is not a known field (did you mean rms_slope?)"),
    ("[surface]\nslope = 0.3\n", "surface.slope is not a known field"),
    ("[surfce]\nrms_slope = 0.3\n", "surfce is not a known field (did you mean surface?)"),
])
def test_typo_inside_a_table_is_named_before_required_fields(needle, table):
    from simulate.config import ConfigError, parse_config

    text = BASE.replace("[surface]\nrms_slope = 0.3\n", table)
    with pytest.raises(ConfigError) as info:
        parse_config(text, "red.toml")
    assert str(info.value) == f"red.toml: {needle}" or str(info.value).startswith(f"red.toml: {needle}")


def test_a_missing_field_beside_a_known_similar_one_is_still_missing():
    # mu_a is a real field close to the missing mu_s: not to be called a typo
    from simulate.config import ConfigError, parse_config

    with pytest.raises(ConfigError, match=r"medium\.mu_s is required"):
        parse_config(BASE.replace("mu_s = 1.0\n", ""), "red.toml")
