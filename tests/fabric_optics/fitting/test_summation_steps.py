"""The fit's structured model and ``simulate fabric``'s share their steps; where the fit has its own
(the in-place symmetrisation of the exit table), it equals the simulate one."""

from __future__ import annotations

import numpy as np

from simulate.fabric import structure as ST
from simulate.fiber import farfield as FF
from simulate.structwalk import walk as fit_structure


def test_the_fits_in_place_symmetrisation_is_the_exit_tables():
    """:func:`simulate.structwalk.walk._symmetrise` (in place, compiled) against
    :func:`simulate.fiber.farfield._symmetrised` on a random table with odd and even axes."""
    rng = np.random.default_rng(4)
    T = rng.random((2, 5, 6, 3, 4, 7))
    expect = FF._symmetrised(T)
    got = T.copy()
    fit_structure._symmetrise(got)
    np.testing.assert_allclose(got, expect, rtol=1e-15, atol=0)
    assert not np.allclose(expect, T)           # the symmetrisation is not the identity here


def test_the_fit_uses_the_summations_steps(monkeypatch):
    """The fit's surface term and halves go through simulate.fabric.structure's functions (one implementation
    of each step): replacing them there changes what the fit computes."""
    facets = ST.flat_facets(ST.StructureSpec(warp_twist_deg=10.0))
    w_i = np.array([[0.3, 0.1, np.sqrt(1 - 0.1)]])
    w_o = np.array([[-0.2, 0.3, np.sqrt(1 - 0.13)]])

    class Config:
        structure = ST.StructureSpec()
        rms_slope, n_host = 0.3, 1.5

    direct = ST.fabric_beta_from_G(ST.surface_layer_table(Config.structure, 0.3, 1.5), facets, w_i, w_o)[:, 0]
    np.testing.assert_array_equal(fit_structure.surface_beta(Config, facets, w_i, w_o), direct)
    assert direct[0] > 0
    calls = []
    real = ST.fabric_beta_from_G
    monkeypatch.setattr(ST, "fabric_beta_from_G", lambda *a: calls.append(1) or real(*a))
    fit_structure.surface_beta(Config, facets, w_i, w_o)
    assert calls == [1]
