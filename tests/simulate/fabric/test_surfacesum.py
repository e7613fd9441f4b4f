"""The structured summation's surface term from what does not depend on the RMS slope, formed once
(simulate.fabric.surfacesum.SurfaceSum): equal bit for bit to the surface table's facet sum
(simulate.fabric.structure.surface_layer_table through fabric_beta_from_G) at every slope it is asked, in any
order, for a felt's inclined facets and a woven structure's twisted ones (the fit problem's use of it:
tests/fabric_optics/fitting/test_surface_lattice.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.fabric import structure as ST
from simulate.fabric.surfacesum import SurfaceSum
from simulate.optics.microfacet import directions_deg


def _geometries(n: int = 30, seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Random pairs with the plan's special cases: the normal, in-plane and retro directions, azimuths on grid
    nodes (a coordinate exactly on a node of the layer grid), grazing exits."""
    rng = np.random.default_rng(seed)
    th_i = np.concatenate([[0.0, 30.0, 45.0, 60.0, 27.76, 78.56], rng.uniform(0.0, 80.0, n)])
    ph_i = np.concatenate([[0.0, 0.0, 90.0, 180.0, 0.0, 0.0], rng.uniform(0.0, 360.0, n)])
    th_o = np.concatenate([[30.0, 30.0, 45.0, 60.0, 27.76, 89.0], rng.uniform(0.0, 88.0, n)])
    ph_o = np.concatenate([[180.0, 180.0, 90.0, 180.0, 0.0, 180.0], rng.uniform(0.0, 360.0, n)])
    return directions_deg(th_i, ph_i), directions_deg(th_o, ph_o)


def _table_beta(spec: ST.StructureSpec, facets, m: float, n_host: float, w_i, w_o) -> np.ndarray:
    return ST.fabric_beta_from_G(ST.surface_layer_table(spec, m, n_host), facets, w_i, w_o)[:, 0]


@pytest.mark.parametrize("spec", [ST.StructureSpec(kind="nonwoven", felt_spread_deg=15.0),
                                  ST.StructureSpec(kind="woven", warp_twist_deg=24.0, weft_twist_deg=10.0)],
                         ids=["felt", "woven"])
def test_the_surface_sum_is_the_surface_tables_facet_sum_bit_for_bit(spec):
    facets = ST.facets_for(spec, None)
    w_i, w_o = _geometries()
    n_host = 1.51
    surface = SurfaceSum(facets, w_i, w_o, n_host, spec.spacing_ratio)
    assert 0 < surface.cells.size < np.prod(surface.shape)        # only the cells the lookups reach
    # slopes in an order that returns to an earlier one: each evaluation stands on its own
    for m in (0.213, 0.05, 0.4, 0.9, 0.213, 0.1234567):
        got = surface.beta(m)
        expect = _table_beta(spec, facets, m, n_host, w_i, w_o)
        assert np.count_nonzero(expect) > 0.8 * expect.size
        np.testing.assert_array_equal(got, expect)


def test_the_surface_sum_belongs_to_its_host_index_and_geometries():
    """Built for one host index and set of geometries, a surface sum is not the term of another: the cached
    geometry (the Fresnel factor, the cells) is the one it was built with."""
    spec = ST.StructureSpec(kind="nonwoven", felt_spread_deg=0.0)
    facets = ST.facets_for(spec, None)
    w_i, w_o = _geometries(8)
    surface = SurfaceSum(facets, w_i, w_o, 1.51, spec.spacing_ratio)
    other_index = _table_beta(spec, facets, 0.2, 1.6, w_i, w_o)
    assert not np.array_equal(surface.beta(0.2), other_index)
    np.testing.assert_array_equal(SurfaceSum(facets, w_i, w_o, 1.6, spec.spacing_ratio).beta(0.2), other_index)
    with pytest.raises(ValueError, match="RMS slope"):
        surface.beta(0.0)
    with pytest.raises(ValueError, match="RMS slope"):
        surface.beta(math.nan)

