"""``simulate fit --resume`` does not trust its state files: fit-state.json and mc-state.json are checked field by
field, and anything malformed, out of bounds, oversized or not a regular file is refused naming the file and the
field (fabric_optics.fitting.state)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.state import MAX_STATE_BYTES, STATE_NAME, STATE_SCHEMA, load_state, read_state_json


def _good(problem) -> dict:
    return {"schema": STATE_SCHEMA, "identity": problem.identity(), "x": [0.9, 0.35],
            "names": [p.name for p in problem.free], "objective": 0.2,
            "photons": {"0:0": 50000, "0:1": 50000}, "evaluations": 12}


def _write(tmp_path, doc) -> None:
    (tmp_path / STATE_NAME).write_text(doc if isinstance(doc, str) else json.dumps(doc), encoding="utf-8")


def test_a_well_formed_state_is_read_as_written(base_problem, tmp_path):
    _write(tmp_path, _good(base_problem))
    state = load_state(tmp_path, base_problem)
    np.testing.assert_array_equal(state["x"], [0.9, 0.35])
    assert state["photons"] == {"0:0": 50000, "0:1": 50000} and state["objective"] == 0.2


@pytest.mark.parametrize("change, field", [
    (lambda d: "null", "JSON null"),
    (lambda d: "[]", "JSON list"),
    (lambda d: "[" * 100_000 + "]" * 100_000, "nested deeper"),
    (lambda d: json.dumps({**d, "z": [[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]}), "nested deeper"),
    (lambda d: json.dumps({**d, "x": [float("nan"), 0.3]}), "is nan, not a finite number"),
    (lambda d: json.dumps({**d, "x": [0.9, float("inf")]}), "is inf, not a finite number"),
    (lambda d: {**d, "x": ["a", 0.3]}, "'x[0] (fiber.dye.bands[0].peak_per_um)' is \"a\""),
    (lambda d: {**d, "x": [True, 0.3]}, "not a number"),
    (lambda d: {**d, "x": []}, "'x' has 0 entries; this fit has 2"),
    (lambda d: {**d, "x": 0.3}, "not a list of 2"),
    (lambda d: {**d, "x": [1e308, 0.3]}, "outside [0.3, 3]"),
    (lambda d: {**d, "x": [0.9, -5]}, "'x[1] (surface.rms_slope)' is -5, outside [0.1, 0.8]"),
    (lambda d: {k: v for k, v in d.items() if k != "x"}, "'x' is missing"),
    (lambda d: {**d, "objective": -1}, "'objective' is -1"),
    (lambda d: {**d, "photons": -1}, "'photons' is -1, not an object"),
    (lambda d: {**d, "photons": {"0:0": -1}}, "'photons.0:0' is -1"),
    (lambda d: {**d, "photons": {"0:0": 10**18}}, "'photons.0:0' is 1e+18, outside"),
    (lambda d: {**d, "photons": {"0:0": 1e18}}, "not an integer"),
    (lambda d: {**d, "photons": {"0:0": 1}}, "'photons.0:0' is 1, outside [2000,"),
    (lambda d: {**d, "photons": {"0:0": 10**9}}, "'photons.0:0' is 1e+09, outside"),
    (lambda d: {**d, "photons": {"0:0": 50001}}, "not whole batches of 2000"),
    (lambda d: {**d, "evaluations": 10**400}, "'evaluations' is a 401-digit integer"),
    (lambda d: {**d, "objective": 10**400}, "'objective' is a 401-digit integer"),
    (lambda d: {**d, "x": [10**400, 0.3]}, "401-digit integer"),
    (lambda d: {**d, "names": ["other"]}, "'names'"),
])
def test_a_malformed_state_is_refused_naming_the_file_and_field(base_problem, tmp_path, change, field):
    _write(tmp_path, change(_good(base_problem)))
    with pytest.raises(FitError) as err:
        load_state(tmp_path, base_problem)
    text = str(err.value)
    assert field in text and str(tmp_path / STATE_NAME) in text and "\n" not in text
    assert "run without --resume" in text


def test_an_oversized_state_is_refused_before_it_is_parsed(base_problem, tmp_path):
    _write(tmp_path, {**_good(base_problem), "x": [0.9] * 300_000})
    assert (tmp_path / STATE_NAME).stat().st_size > MAX_STATE_BYTES
    with pytest.raises(FitError, match="more than a state file's limit"):
        load_state(tmp_path, base_problem)


@pytest.mark.parametrize("kind", ["fifo", "device", "directory"])
def test_a_state_that_is_not_a_regular_file_is_refused_without_blocking(base_problem, tmp_path, kind):
    path = tmp_path / STATE_NAME
    if kind == "fifo":
        os.mkfifo(path)       # a blocking open would hang here: the read opens it non-blocking
    elif kind == "device":
        os.symlink("/dev/zero", path)
    else:
        path.mkdir()
    with pytest.raises(FitError, match=f"is a {'FIFO' if kind == 'fifo' else kind}"):
        load_state(tmp_path, base_problem)


def test_no_state_file_is_none_but_a_dangling_link_is_refused(tmp_path):
    assert read_state_json(tmp_path / STATE_NAME) is None
    os.symlink(tmp_path / "gone.json", tmp_path / STATE_NAME)
    with pytest.raises(FitError, match="missing target"):
        read_state_json(tmp_path / STATE_NAME)


# --- mc-state.json (the Monte Carlo fit's runs) ---------------------------------------------------------


def _mc_problem():
    from fabric_optics.fitting.spacemapping import MCFitProblem
    from fabric_optics.fitting.spec import parse_free

    from .test_fit_mc import FREE, WL6, _felt, _flat

    start = _felt(-0.9, -2.1)
    return MCFitProblem(start, _flat(WL6), parse_free([FREE], start), target_rel_err=0.2, seed=2, wavelengths_nm=WL6)


def _mc_state(problem, **rec_changes) -> dict:
    from fabric_optics.fitting.state import MC_SCHEMA

    rec = {"x": [-0.9, -2.1], "seconds": 1.0, "rays": 10, "rel_err": 0.1, "objective": 0.5, "nrmse": 0.3,
           "dh": float("nan"), "ds": 0.01, "file": "run-0.npz",
           "proposal": {"kind": "surrogate fit", "x": [-0.6, -2.4], "u": [0.1, 0.1], "surrogate_evaluations": 9,
                        "notes": []}}
    rec.update(rec_changes)
    return {"schema": MC_SCHEMA, "identity": problem.identity(), "iterations": [rec]}


@pytest.mark.parametrize("change, field", [
    ({"x": [5.0, -2.1]}, "'iterations[0].x[0] (fiber.dye.log10_per_um[0])' is 5, outside [-3, 0]"),
    ({"x": [-0.9]}, "'iterations[0].x' has 1 entries"),
    ({"file": "../../secret.npz"}, "'iterations[0].file'"),
    ({"objective": "low"}, "'iterations[0].objective'"),
    ({"rays": -3}, "'iterations[0].rays' is -3"),
    ({"proposal": {"kind": "surrogate fit", "x": [-0.6, 9.0], "u": [0.1, 0.1], "surrogate_evaluations": 9}},
     "'iterations[0].proposal.x[1] (fiber.dye.log10_per_um[1])' is 9"),
    ({"proposal": {"kind": "surrogate fit", "x": [-0.6, -2.4], "u": [0.1], "surrogate_evaluations": 9}},
     "'iterations[0].proposal.u'"),
    ({"fine_runs": {"7": {}}}, "names parameter '7'"),
])
def test_a_malformed_mc_state_is_refused_naming_the_field(tmp_path, change, field):
    from fabric_optics.fitting.spacemapping import run_mc_fit
    from fabric_optics.fitting.state import MC_STATE

    problem = _mc_problem()
    (tmp_path / MC_STATE).write_text(json.dumps(_mc_state(problem, **change)))
    with pytest.raises(FitError) as err:
        run_mc_fit(problem, out=tmp_path, resume=True)        # refused before any walk
    assert field in str(err.value) and str(tmp_path / MC_STATE) in str(err.value)


def test_a_well_formed_mc_state_passes_and_a_run_file_of_the_wrong_shape_is_refused(tmp_path):
    from fabric_optics.fitting.state import MC_RUNS_DIR, MC_STATE, MCState

    problem = _mc_problem()
    (tmp_path / MC_STATE).write_text(json.dumps(_mc_state(problem)))
    shape = (len(problem.geometries), problem.wavelengths_nm.size)
    state = MCState(tmp_path, problem.identity(), shape)
    state.load(problem)
    assert state.run(0, np.array([-0.9, -2.1])) is None             # no run file: the run is made again
    (tmp_path / MC_RUNS_DIR).mkdir()
    np.savez(tmp_path / MC_RUNS_DIR / "run-0.npz", x=[-0.9, -2.1], beta=np.ones((2, 2)), u_beta=np.ones((2, 2)))
    with pytest.raises(FitError, match=r"run-0\.npz: holds tables of shape \(2, 2\)"):
        state.run(0, np.array([-0.9, -2.1]))
    np.savez(tmp_path / MC_RUNS_DIR / "run-0.npz", x=[-0.9, -2.1], beta=np.ones(shape), u_beta=np.ones(shape))
    assert state.run(0, np.array([-0.9, -2.1])).beta.shape == shape


# --- checkpoint files (walks/*.npz, mc-runs/run-K.npz) read as untrusted input --------------------------


def _arrays():
    return {"x": np.array([-0.9, -2.1]), "beta": np.ones((3, 4)), "u_beta": np.full((3, 4), 0.01)}


def _spec():
    return {"x": ("f", 1), "beta": ("f", 2), "u_beta": ("f", 2)}


def _bomb(path):
    """A zip of the right members whose ``beta`` is 200 MB of zeros deflated to a few hundred kB."""
    import io
    import zipfile

    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        for name, a in _arrays().items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.zeros(25_000_000) if name == "beta" else a)
            z.writestr(f"{name}.npy", buf.getvalue())


@pytest.mark.parametrize("make, says", [
    (lambda p: os.mkfifo(p), "not a regular file"),
    (lambda p: p.mkdir(), "not a regular file"),
    (lambda p: p.write_bytes(b"\x00" * 100), "truncated or corrupt"),
    (lambda p: (np.savez(p, **_arrays()), p.write_bytes(p.read_bytes()[:-200])), "truncated or corrupt"),
    (lambda p: _bomb(p), "would expand to 200,000,128 bytes"),
    (lambda p: np.savez(p, x=np.array([-0.9, -2.1]), beta=np.array([{"a": 1}], dtype=object),
                        u_beta=np.ones((3, 4))), "array 'beta' is object"),
    (lambda p: np.savez(p, x=np.array([-0.9, -2.1]), beta=np.ones((3, 4), np.float32), u_beta=np.ones((3, 4))),
     "array 'beta' is float32"),
    (lambda p: np.savez(p, x=np.array([-0.9, -2.1]), beta=np.ones(12), u_beta=np.ones((3, 4))), "of shape (12,)"),
    (lambda p: np.savez(p, x=np.array([-0.9, -2.1]), beta=np.full((3, 4), np.nan), u_beta=np.ones((3, 4))),
     "not finite"),
    (lambda p: np.savez(p, x=np.array([-0.9, -2.1]), beta=np.ones((3, 4))), "not the arrays"),
    (lambda p: p.write_bytes(b"\x00" * 2000), "more than a checkpoint's limit of 1,000"),
])
def test_a_checkpoint_file_is_checked_before_it_is_loaded(tmp_path, make, says):
    """No special file is opened for a blocking read, nothing is decompressed past what the zip declares, no
    pickle is loaded, and a file that is not the checkpoint's is refused in one line naming it."""
    from fabric_optics.fitting.state import read_npz

    path = tmp_path / "run-0.npz"
    make(path)
    with pytest.raises(FitError) as err:
        read_npz(path, _spec(), max_bytes=1000 if "limit of 1,000" in says else 64_000_000)
    text = str(err.value)
    assert str(path) in text and says in text and "\n" not in text, text


def test_a_good_checkpoint_file_is_read_and_a_missing_one_is_none(tmp_path):
    from fabric_optics.fitting.state import read_npz

    assert read_npz(tmp_path / "run-0.npz", _spec()) is None
    np.savez(tmp_path / "run-0.npz", **_arrays())
    got = read_npz(tmp_path / "run-0.npz", _spec())
    for name, a in _arrays().items():
        np.testing.assert_array_equal(got[name], a)


def test_a_walk_checkpoint_that_is_not_a_run_is_refused(tmp_path):
    from fabric_optics.fitting.state import WalkCheckpoint

    cp = WalkCheckpoint(tmp_path, "id", (), np.zeros(2), None)
    cp.put("0:0", np.ones((2, 3)), np.ones((2, 3)), 4000, 1.5)
    value, u, photons, n = cp.get("0:0")
    assert photons == 4000 and n == 1.5 and value.shape == (2, 3)
    path = cp._path("0:0")
    np.savez(path, value=np.ones((2, 3)), u=np.ones((2, 3)), photons=np.int64(1), scatterings=np.float64(1.0))
    with pytest.raises(FitError, match="records 1 photons"):
        cp.get("0:0")
    path.write_bytes(path.read_bytes()[:50])
    with pytest.raises(FitError, match="truncated or corrupt"):
        cp.get("0:0")


def test_simulate_fit_resume_on_a_truncated_run_file_is_one_line_exit_2(tmp_path, capsys):
    """The command line: a truncated mc-runs/run-0.npz under a valid mc-state.json is one line naming the file,
    exit 2, before any Monte Carlo run."""
    from fabric_optics import api
    from fabric_optics.cli.simulate import main
    from fabric_optics.fitting.state import MC_RUNS_DIR, MC_STATE
    from gonio.data import write_dataset

    from .test_fit_mc import FREE, WL6, _felt, _flat

    (tmp_path / "felt.toml").write_text(_felt(-0.9, -2.1).text)
    write_dataset(_flat(WL6), tmp_path / "m")
    out = tmp_path / "fit"
    out.mkdir()
    wl = ",".join(f"{w:g}" for w in WL6)
    problem = api.prepare_fit(tmp_path / "felt.toml", tmp_path / "m", FREE, out, method="mc", target_rel_err=0.2,
                              seed=2, wavelengths_nm=WL6, resume=True).problem
    (out / MC_STATE).write_text(json.dumps(_mc_state(problem)))
    (out / MC_RUNS_DIR).mkdir()
    shape = (len(problem.geometries), WL6.size)
    np.savez(out / MC_RUNS_DIR / "run-0.npz", x=[-0.9, -2.1], beta=np.ones(shape), u_beta=np.ones(shape))
    run_file = out / MC_RUNS_DIR / "run-0.npz"
    run_file.write_bytes(run_file.read_bytes()[:-300])
    code = main(["fit", str(tmp_path / "felt.toml"), str(tmp_path / "m"), "--method", "mc", "--free", FREE,
                 "--target-rel-err", "0.2", "--seed", "2", "--wavelengths", wl, "--out", str(out), "--resume",
                 "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and str(run_file) in err and "truncated" in err, err


# --- a full disk while the fit checkpoints ---------------------------------------------------------------


def test_a_full_disk_while_checkpointing_is_one_line_and_leaves_no_temporary_file(tmp_path, monkeypatch):
    import errno

    from fabric_optics.fitting.state import WALKS_DIR, WalkCheckpoint, write_json_atomic

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(np, "savez", full)
    cp = WalkCheckpoint(tmp_path, "id", (), np.zeros(2), None)
    with pytest.raises(FitError) as err:
        cp.put("0:0", np.zeros(3), np.zeros(3), 10, 1.0)
    assert "No space left on device" in str(err.value) and "--resume" in str(err.value)
    assert list((tmp_path / WALKS_DIR).iterdir()) == []
    monkeypatch.setattr(os, "fsync", full)
    (tmp_path / STATE_NAME).write_text('{"x": [1]}')
    with pytest.raises(FitError, match=f"{tmp_path / STATE_NAME}: cannot write \\(No space left on device\\)"):
        write_json_atomic(tmp_path / STATE_NAME, {"x": [2]})
    assert sorted(p.name for p in tmp_path.iterdir()) == [STATE_NAME, WALKS_DIR]    # no .fit-state.json.tmp
    assert (tmp_path / STATE_NAME).read_text() == '{"x": [1]}'                      # the previous state kept
