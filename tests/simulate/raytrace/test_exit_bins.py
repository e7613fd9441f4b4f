"""The yarn table's exit-direction bins (``[method] exit_bins``): a refinement, and what a run uses."""

from __future__ import annotations

import logging

import numpy as np

from fabric_optics.cli.simulate import main
from gonio.data.dataset import read_dataset
from simulate import fiber as F
from simulate.media.medium import HGMedium
from simulate.raytrace import estimate as E
from simulate.raytrace.yarn import yarn_table
from tests.simulate.raytrace.test_felt import FELT, PLAN


def test_finer_exit_bins_split_the_coarse_ones_exactly():
    """The walk does not depend on the bins (same photons at the same seed), so the 10 x 20 bins of a
    table summed in pairs of mu and of phi bins are the 5 x 10 table: the finer bins only say where in
    a coarse bin the light left, which the tracer otherwise draws uniformly in projected solid angle."""
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.3, mu_a=0.01, g=0.5), 0.35, 10.0)
    coarse = yarn_table(fib, [550.0], photons_per_row=2000, seed=3, n_mu=5, n_phi=10, cache=False)
    fine = yarn_table(fib, [550.0], photons_per_row=2000, seed=3, n_mu=10, n_phi=20, cache=False)
    assert (coarse.n_mu, coarse.n_phi, fine.n_mu, fine.n_phi) == (5, 10, 10, 20)
    j, k, _, L = fine.T.shape
    summed = fine.T.reshape(j, k, -1, fine.n_v, 5, 2, 10, 2, L).sum(axis=(5, 7))
    np.testing.assert_allclose(summed, coarse.T.reshape(j, k, -1, coarse.n_v, 5, 10, L),
                               rtol=1e-9, atol=1e-12 * float(coarse.T.max()))
    np.testing.assert_allclose(fine.exit_fraction, coarse.exit_fraction, rtol=1e-12)


def test_a_clear_fibers_exits_are_not_uniform_within_the_coarse_bins():
    """Why the bins are a setting: the tracer draws an exit direction uniformly in projected solid angle
    within its bin, right where the fiber scatters (the two mu halves of a coarse bin then hold
    ``(mu_2^2 - mu_1^2)``-proportional shares), not where a nearly clear fiber refracts its light out:
    there the coarse bins' halves hold shares 20-40 % off the uniform split."""
    expect = np.array([(i + 1) ** 2 - i ** 2 for i in range(10)], float).reshape(5, 2)
    uniform = expect[:, 1] / expect[:, 0]

    def split(mu_s: float) -> np.ndarray:
        fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=mu_s, mu_a=0.0, g=0.5), 0.35, 10.0)
        t = yarn_table(fib, [550.0], photons_per_row=4000, seed=3, n_mu=10, n_phi=20, cache=False)
        j, k, _, L = t.T.shape
        per_mu = t.T.reshape(j, k, -1, t.n_v, 10, 20, L)[..., 0].sum(axis=(0, 1, 2, 3, 5)).reshape(5, 2)
        return per_mu[:, 1] / per_mu[:, 0] / uniform     # 1: uniform within the coarse bin

    scattering, clear = split(0.3), split(0.002)
    # the four bins off the grazing one (Fresnel cuts the grazing exits in both)
    assert np.all(np.abs(scattering[1:] - 1.0) < 0.15), scattering
    assert np.max(np.abs(clear[1:] - 1.0)) > 0.3, clear


CLEAR_FELT = FELT.replace("mu_s = 0.8", "mu_s = 0.01")     # 2 R mu_s = 0.2: a nearly clear fiber


def test_the_clear_fiber_note_names_nearly_clear_fibers_at_coarse_azimuth_bins():
    clear = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.01, mu_a=0.0, g=0.5), 0.35, 10.0)
    turbid = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.3, mu_a=0.0, g=0.5), 0.35, 10.0)
    note = E.clear_fiber_note(clear, [450.0, 550.0, 650.0], (5, 10))
    assert note is not None and "0.2 scattering events" in note and "exit_bins" in note
    assert E.clear_fiber_note(turbid, [550.0], (5, 10)) is None        # 2 R mu_s = 6
    assert E.clear_fiber_note(clear, [550.0], (5, 20)) is None          # azimuths finer than the default's


def _run_felt(tmp_path, caplog, text: str, name: str):
    cfg = tmp_path / f"{name}.toml"
    cfg.write_text(text)
    plan = tmp_path / "tiny.toml"
    plan.write_text(PLAN)
    out = tmp_path / name
    with caplog.at_level(logging.WARNING, logger="simulate.products"):
        assert main(["fabric", str(cfg), "--method", "mc", "--plan", str(plan), "--out", str(out),
                     "--target-rel-err", "0.1", "--no-progress"]) == 0
    warned = sum("nearly clear" in r.getMessage() for r in caplog.records)
    caplog.clear()
    ds = read_dataset(out)
    assert np.all(ds.table["beta"] > 0)
    return warned, ds.meta["provenance"]["fiber_info"]["table"]["grid"]


def test_a_felt_of_clear_fibers_at_coarse_bins_warns_once(tmp_path, capsys, caplog):
    """Bins the config gives are used; coarse azimuth bins on nearly clear fibers say so in one warning."""
    warned, grid = _run_felt(tmp_path, caplog, CLEAR_FELT + "[method]\nexit_bins = [4, 8]\n", "coarse")
    capsys.readouterr()
    assert warned == 1 and grid[2:] == [4, 8]


def test_simulate_fabric_traces_the_felt_at_the_default_bins_without_a_warning(tmp_path, capsys, caplog):
    """The default exit bins resolve a clear fiber's exit cones: used when the config gives none, no warning."""
    warned, grid = _run_felt(tmp_path, caplog, CLEAR_FELT, "default")
    capsys.readouterr()
    assert warned == 0 and grid[2:] == [10, 20]
