"""A dye's felt Monte Carlo re-weighted from a traced run (simulate.raytrace.reweight): the traced dye gives the traced
result, another dye agrees with a re-traced run within combined standard errors, and a fiber changed in more than
its dye is refused. Tiny felts, fixed seeds."""

from __future__ import annotations

import numpy as np
import pytest

from simulate import fabric as fab
from simulate import fiber as F
from simulate import raytrace as W
from simulate.fabric import structure as ST
from simulate.geometry.felt import felt_mesh
from simulate.media.medium import HGMedium
from simulate.raytrace import reweight as RW


def _fiber(mu_a: float, radius: float = 10.0) -> F.Fiber:
    return F.Fiber(radius, 1.5, HGMedium(mu_s=0.8, mu_a=mu_a, g=0.5), 0.35, 10.0)


@pytest.fixture(scope="module")
def felt_case():
    """Two realisations of a four-layer felt, one incidence (20 deg) and two detectors, traced at mu_a 0.01 /um
    with a record (seed 0, one thread)."""
    spec = ST.StructureSpec(kind="nonwoven", felt_spread_deg=15.0, layers=4)
    meshes = (felt_mesh(spec, 10.0, seed=0), felt_mesh(spec, 10.0, seed=1))
    w_i = fab.directions_deg(np.array([20.0, 20.0]), np.zeros(2))
    w_o = fab.directions_deg(np.array([10.0, 50.0]), np.array([180.0, 0.0]))
    wl = np.array([550.0])
    record: dict = {}
    beta, u, info = W.fabric_beta(meshes, _fiber(0.01), w_i, w_o, wl, target_rel_err=0.08, seed=0, threads=1,
                                  record=record)
    return meshes, w_i, w_o, wl, record, beta, u


def test_the_traced_dye_re_weighted_is_the_traced_run(felt_case):
    meshes, w_i, w_o, wl, record, beta, u = felt_case
    assert RW.record_bytes(record) > 0
    b, ub, info = RW.reweighted_beta(record, RW.new_tables(record, _fiber(0.01)))
    # the same events replayed with the same table, in the tracer's order: equal to rounding
    np.testing.assert_allclose(b, beta, rtol=1e-12, atol=0.0)
    np.testing.assert_allclose(ub, u, rtol=1e-12, atol=0.0)
    assert info["spread"] == pytest.approx(1.0, rel=1e-9)


def test_another_dye_re_weighted_agrees_with_a_re_traced_run(felt_case):
    """mu_a 0.01 -> 0.04 /um: the re-weighted run is within 4 combined standard errors of a run traced at 0.04 /um
    (same seed and tables), and both are far (> 5 combined standard errors) from the traced dye's: the test would
    see a re-weighting that left the dye out."""
    meshes, w_i, w_o, wl, record, beta0, u0 = felt_case
    b, ub, info = RW.reweighted_beta(record, RW.new_tables(record, _fiber(0.04)))
    ref, u_ref, _ = W.fabric_beta(meshes, _fiber(0.04), w_i, w_o, wl, target_rel_err=0.08, seed=0, threads=1)
    z = (b - ref) / np.sqrt(ub ** 2 + u_ref ** 2)
    assert np.all(np.abs(z) < 4.0), z
    assert np.all(np.abs(ref - beta0) > 5.0 * np.sqrt(u_ref ** 2 + u0 ** 2))
    assert np.all(b < beta0)          # more absorption, less light
    assert info["rays"] > 0 and info["spread"] > 0.0


def test_only_a_dye_change_is_re_weighted(felt_case):
    record = felt_case[4]
    assert RW.same_but_dye(_fiber(0.01), _fiber(0.3))
    assert not RW.same_but_dye(_fiber(0.01), _fiber(0.01, radius=12.0))
    scattering = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.9, mu_a=0.01, g=0.5), 0.35, 10.0)
    assert not RW.same_but_dye(_fiber(0.01), scattering)
    import dataclasses

    other = RW.new_tables(record, _fiber(0.02))[0]
    wider = dataclasses.replace(other, c_bar=other.c_bar * 1.01)
    with pytest.raises(ValueError, match="more than the dye"):
        RW.new_tables(record, None, (wider, wider))


def _base(a: np.ndarray) -> np.ndarray:
    while isinstance(a.base, np.ndarray):
        a = a.base
    return a


def test_the_halves_are_walked_one_at_a_time_as_the_traced_run_s(felt_case, monkeypatch, tmp_path):
    """Each half made on demand is bit for bit the one ``table_halves`` walks for both at once (what a trace of
    that dye reads), and a re-weighting lets a half go before it asks for the next: the two are never held
    together (weak references to each table's memory, checked as the next half is asked for)."""
    import weakref
    from collections.abc import Sequence

    from simulate.fiber import tablecache
    from simulate.raytrace.yarn import table_halves

    monkeypatch.setenv(tablecache.ENV_DIR, str(tmp_path / "cache"))
    monkeypatch.setenv(tablecache.ENV_DISABLE, "1")      # walked, not read: the walk itself is compared
    record = felt_case[4]
    fiber = _fiber(0.03)
    halves = RW.new_tables(record, fiber)
    assert len(halves) == 2
    both = table_halves(fiber, record["wavelengths_nm"], record["photons_per_row"], record["seed"], None,
                        **record["grid"])
    for h in range(2):
        one = halves[h]
        assert one.T.tobytes() == both[h].T.tobytes()
        assert one.c_bar.tobytes() == both[h].c_bar.tobytes() and one.tau.tobytes() == both[h].tau.tobytes()
    del one, both

    class Watched(Sequence):
        def __init__(self) -> None:
            self.alive: list = []

        def __len__(self) -> int:
            return len(halves)

        def __getitem__(self, h):  # type: ignore[override]
            assert all(r() is None for r in self.alive), f"half {h} asked for while another is held"
            table = halves[h]
            self.alive.append(weakref.ref(_base(table.T)))
            return table

    watched = Watched()
    b, ub, _ = RW.reweighted_beta(record, watched)
    assert len(watched.alive) == 2
    b_all, ub_all, _ = RW.reweighted_beta(record, tuple(halves[h] for h in range(2)))
    assert b.tobytes() == b_all.tobytes() and ub.tobytes() == ub_all.tobytes()
