"""Reading an absorption table (simulate.fiber.absorption.AbsorptionTable.__call__): the vectorised monotone
cubic equals scipy's PchipInterpolator per wavelength, and the linear fallbacks equal np.interp."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from simulate.fiber.absorption import AbsorptionTable, _x, absorption_nodes, pchip_at


def _table(seed: int, P: int = 7, L: int = 5, K: int = 16) -> AbsorptionTable:
    rng = np.random.default_rng(seed)
    nodes = absorption_nodes(3.0, K)
    # decreasing in the absorption (as a fabric's beta), with noise that breaks monotonicity in places
    R = np.exp(-np.cumsum(rng.uniform(0.0, 0.8, (P, L, K)), axis=2)) * rng.uniform(0.5, 1.5, (P, L, K))
    R[0, 1, 3] = 0.0           # an output without scores at one node: read linearly in R
    R[2, 4, :] = 0.0           # no scores at all
    u = R * rng.uniform(0.01, 0.1, R.shape)
    return AbsorptionTable(R=R, u_R=u, nodes=nodes, wavelengths_nm=np.linspace(400.0, 700.0, L))


def test_pchip_at_is_scipys_pchip():
    rng = np.random.default_rng(3)
    x_nodes = np.sort(rng.uniform(-9.0, 1.0, 9))
    y = rng.normal(size=(4, 6, 9))
    y[1, 2] = np.linspace(0.0, 1.0, 9)        # straight line, and flat pieces (zero slopes)
    y[3, 0, 2:5] = 0.5
    x = np.concatenate([[x_nodes[0], x_nodes[-1]], rng.uniform(x_nodes[0], x_nodes[-1], 4)])
    got = pchip_at(x_nodes, y, x)
    for l in range(6):
        ref = PchipInterpolator(x_nodes, y[:, l, :], axis=1)(x[l])
        np.testing.assert_allclose(got[:, l], ref, rtol=1e-12, atol=1e-12)
    # three nodes and two nodes (scipy's special case)
    for k in (2, 3):
        mid = 0.5 * (x_nodes[0] + x_nodes[k - 1])
        got = pchip_at(x_nodes[:k], y[..., :k], np.full(6, mid))
        ref = np.stack([PchipInterpolator(x_nodes[:k], y[:, l, :k], axis=1)(mid) for l in range(6)], axis=1)
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


def test_table_read_equals_the_per_wavelength_reference():
    table = _table(1)
    rng = np.random.default_rng(2)
    for mu in (rng.uniform(0.0, 3.0, 5), table.nodes[[0, 3, 7, 15, 9]], np.zeros(5), np.full(5, 3.0)):
        R, u = table(mu)
        x_nodes, x = _x(table.nodes), _x(mu)
        for l in range(5):
            vals = table.R[:, l, :]
            positive = np.all(vals > 0, axis=1)
            ref = np.empty(vals.shape[0])
            ref[positive] = np.exp(PchipInterpolator(x_nodes, np.log(vals[positive]), axis=1)(x[l]))
            ref[~positive] = [np.interp(x[l], x_nodes, row) for row in vals[~positive]]
            rel = np.where(vals > 0, table.u_R[:, l, :] / np.where(vals > 0, vals, 1.0), 0.0)
            ref_u = ref * np.array([np.interp(x[l], x_nodes, row) for row in rel])
            np.testing.assert_allclose(R[:, l], ref, rtol=1e-12, atol=0)
            np.testing.assert_allclose(u[:, l], ref_u, rtol=1e-12, atol=0)
    assert np.all(table(np.full(5, 1.0))[0][2, 4] == 0.0)
