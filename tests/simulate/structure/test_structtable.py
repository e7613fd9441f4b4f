"""The compiled facet sum and the fabric-frame table (simulate.fabric.structtable)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.fabric import fiberlayer as FL
from simulate.fabric import structtable as STT
from simulate.fabric import structure as ST
from simulate.fiber import Fiber
from simulate.fiber import farfield as FF
from simulate.geometry import weave as WV
from simulate.media.medium import HGMedium


@pytest.fixture(scope="module")
def layer():
    fiber = Fiber(radius_um=10.0, n_host=1.5, medium=HGMedium(mu_s=0.4, mu_a=0.02, g=0.5), roughness=0.3,
                  cell_width_deg=10)
    table = FF.exit_table(fiber, [450.0, 550.0], w_t=[0.0, 0.5, 0.9], photons_per_row=4_000, seed=2, threads=2)
    return FL.layer_table(table, fiber, step_deg=15.0, phi_step_deg=30.0)


@pytest.fixture(scope="module")
def facets():
    weave = WV.Weave([[1, 0], [0, 1]], spacing_um=300, width_um=250, height_um=100)
    return ST.facets_for(ST.StructureSpec(samples=16, warp_twist_deg=20.0, weft_twist_deg=30.0,
                                          weft_twist="S"), weave)


def _directions(n, seed):
    rng = np.random.default_rng(seed)
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1)[:, None]
    w[:, 2] = np.abs(w[:, 2]) + 0.05
    return w / np.linalg.norm(w, axis=1)[:, None]


def test_compiled_facet_sum_equals_the_generic_sum(layer, facets):
    w_i, w_o = _directions(50, 1), _directions(50, 2)
    fast = ST.fabric_beta_from_G(layer, facets, w_i, w_o)
    generic = ST.fabric_beta_from_G(lambda a, b: layer(a, b), facets, w_i, w_o)
    assert np.all(fast > 0)
    np.testing.assert_allclose(fast, generic, rtol=1e-10)


def test_weave_is_unchanged_by_a_half_turn(layer, facets):
    """A plain weave (twisted or not) turned by 180 deg about its normal is the same fabric."""
    turn = np.diag([-1.0, -1.0, 1.0])
    w_i, w_o = _directions(40, 3), _directions(40, 4)
    a = ST.fabric_beta_from_G(layer, facets, w_i, w_o)
    b = ST.fabric_beta_from_G(layer, facets, w_i @ turn, w_o @ turn)
    np.testing.assert_allclose(a, b, rtol=1e-9)
    # a quarter turn is NOT a symmetry of the twisted weave here (warp Z 20 deg, weft S 30 deg)
    quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    c = ST.fabric_beta_from_G(layer, facets, w_i @ quarter.T, w_o @ quarter.T)
    assert np.max(np.abs(c - a) / a) > 1e-3


def test_fabric_table_reproduces_the_facet_sum(layer, facets):
    ft = STT.fabric_table(layer, facets, step_deg=15.0, phi_step_deg=30.0)
    # at nodes: exact
    w_i = np.array([[math.sin(math.radians(30)) * math.cos(math.radians(60)),
                     math.sin(math.radians(30)) * math.sin(math.radians(60)), math.cos(math.radians(30))]])
    w_o = np.array([[math.sin(math.radians(45)) * math.cos(math.radians(210)),
                     math.sin(math.radians(45)) * math.sin(math.radians(210)), math.cos(math.radians(45))]])
    direct = ST.fabric_beta_from_G(layer, facets, w_i, w_o)
    np.testing.assert_allclose(ft.beta(w_i, w_o), direct, rtol=1e-9)
    # through the half turn (phi_i = 240 is stored as 60)
    turn = np.diag([-1.0, -1.0, 1.0])
    np.testing.assert_allclose(ft.beta(w_i @ turn, w_o @ turn), direct, rtol=1e-9)
    # between nodes: within the grid's interpolation error (15 / 30 deg here; 7.5 / 15 by default)
    w_i, w_o = _directions(200, 5), _directions(200, 6)
    keep = (w_i[:, 2] > 0.3) & (w_o[:, 2] > 0.3)
    a = ft.beta(w_i[keep], w_o[keep])
    b = ST.fabric_beta_from_G(layer, facets, w_i[keep], w_o[keep])
    assert np.sqrt(np.mean(((a - b) / b) ** 2)) < 0.05
