"""The pile table's photons sized for the fabric's target (:data:`simulate.raytrace.estimate.PILE_TABLE`).

The pile's table is the woven Monte Carlo's expensive part; it is given the share of the target its
measured noise needs, the rays the rest. Checked: the wiring (the pile's table and rays take the
pile's split, the fiber's tube keeps its own), that the split adds up to the target and not more, and
that runs with the pile's fewer photons per row still agree within their reported errors.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate import fiber as F
from simulate import raytrace as W
from simulate.fabric import structure as ST
from simulate.geometry import weave
from simulate.geometry.mesh import mesh as weave_mesh
from simulate.media.medium import HGMedium
from simulate.raytrace import estimate as E


class _Stop(Exception):
    pass


@pytest.fixture(scope="module")
def plain_mesh():
    return weave_mesh(weave.preset("plain", points_per_span=6, sides=12))


def _requested(monkeypatch, mesh, volume: str, target: float) -> dict:
    """What ``fabric_beta`` asks of the table and of the rays (both stubbed: no Monte Carlo)."""
    seen: dict = {}

    def halves(walked, wl, photons_per_row, seed, threads, cache=True, **held):
        seen.update(photons=photons_per_row, held=held, radius=walked.radius_um)
        return (object(), object())

    def trace(*args, **kw):
        seen["ray_target"] = kw["target_rel_err"]
        raise _Stop

    monkeypatch.setattr(E, "table_halves", halves)
    monkeypatch.setattr(E, "FiberSurface", lambda *a, **k: None)
    monkeypatch.setattr(E, "trace", trace)
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.35, 10.0)
    with pytest.raises(_Stop):
        E.fabric_beta(mesh, fib, [[0.0, 0.0, 1.0]], [[0.0, 0.0, 1.0]], [550.0], target_rel_err=target,
                      structure=ST.StructureSpec(), volume=volume)
    return seen


@pytest.mark.parametrize("target", [0.005, 0.01])
def test_the_piles_table_and_rays_share_the_target_by_its_measured_noise(monkeypatch, plain_mesh, target):
    pile = _requested(monkeypatch, plain_mesh, "pile", target)
    fiber = _requested(monkeypatch, plain_mesh, "fiber", target)
    # the pile's table: its own noise and share, held groups; far fewer photons than the fiber's rule
    # fabric_beta's own exit bins and axial nodes (a config run passes its [method] exit_bins and axial_nodes)
    grid = {"n_mu": 5, "n_phi": 10, "w_t_nodes": (0.0, 0.25, 0.5, 0.75, 0.95)}
    assert pile["held"] == {"held_log_mu_s": W.pile.HELD_LOG_MU_S, **grid} and fiber["held"] == grid
    assert pile["radius"] > 10.0 and fiber["radius"] == 10.0
    assert pile["photons"] < 0.5 * fiber["photons"]
    # the table's expected error (noise / sqrt(photons per row, both halves)) and the rays' (the mean of
    # the two halves' traces: each target / sqrt 2) add in quadrature to the target, not more, not less
    for got, rule in ((pile, E.PILE_TABLE), (fiber, {"noise": E.TABLE_NOISE})):
        t = rule["noise"] / math.sqrt(2 * got["photons"])
        r = got["ray_target"] / math.sqrt(2.0)
        assert math.hypot(t, r) == pytest.approx(target, rel=0.01)
    # a pile whose rays are cheap takes the larger share of the error in the table
    assert pile["ray_target"] < fiber["ray_target"]


def test_the_piles_floor_at_loose_targets(monkeypatch, plain_mesh):
    """At a loose target the pile's table stops at its floor (per row, both halves together)."""
    pile = _requested(monkeypatch, plain_mesh, "pile", 0.05)
    assert 2 * pile["photons"] == E.PILE_TABLE["min_photons"]
    assert 2 * _requested(monkeypatch, plain_mesh, "fiber", 0.05)["photons"] == E.TABLE_MIN_PHOTONS


def test_pile_runs_at_the_floor_agree_within_their_reported_errors(plain_mesh):
    """Two seeds, two independent pile tables at the floor's photons per row: the fabric agrees within
    the reported ``u_beta`` (which therefore still holds the table's noise at the fewer photons)."""
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.03, g=0.5), 0.35, 10.0)
    t = np.radians([0.0, 30.0, 60.0])
    w_in = np.tile([np.sin(0.5), 0.0, np.cos(0.5)], (3, 1))
    w_out = np.column_stack([np.sin(t), 0 * t, np.cos(t)])
    runs = [E.fabric_beta(plain_mesh, fib, w_in, w_out, [550.0], target_rel_err=0.05, seed=s, threads=2,
                          structure=ST.StructureSpec(), cache=False) for s in (1, 2)]
    (b1, u1, i1), (b2, u2, i2) = runs
    assert i1["yarn_volume"] == "pile" and all(r["table_rel_err"] > 0 for r in i1["incidences"] + i2["incidences"])
    z = (b1 - b2) / np.hypot(u1, u2)
    assert np.max(np.abs(z)) < 4.0, z
