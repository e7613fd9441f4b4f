"""The directional interior return (simulate.fabric.adding): operators against an independent trace, energy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate.fiber import farfield as FF
from simulate.fabric import adding as AD
from simulate.fabric import fiberlayer as FL
from simulate.fabric import interior as IN
from simulate.fiber import Fiber
from simulate.media.medium import HGMedium

R_UM, N_HOST, MU_S, MU_A, G = 10.0, 1.5, 0.4, 0.02, 0.5


def _fiber(mu_a: float = MU_A, mu_s: float = MU_S) -> Fiber:
    return Fiber(radius_um=R_UM, n_host=N_HOST, medium=HGMedium(mu_s=mu_s, mu_a=mu_a, g=G), roughness=0.3,
                 cell_width_deg=10)


@pytest.fixture(scope="module")
def table():
    return FF.exit_table(_fiber(), [550.0], w_t=[0.0, 0.3, 0.6], photons_per_row=20_000, seed=4, threads=2)


@pytest.fixture(scope="module")
def white():
    """A non-absorbing, weakly scattering fiber (much light crosses it) and its exit table."""
    fiber = _fiber(mu_a=0.0, mu_s=0.05)
    return fiber, FF.exit_table(fiber, [550.0], photons_per_row=2_000, seed=1, threads=2)


def _w(w_t: float, beta_deg: float) -> np.ndarray:
    rho = math.sqrt(1.0 - w_t * w_t)
    b = math.radians(beta_deg)
    return np.array([w_t, -rho * math.sin(b), rho * math.cos(b)])


def _lower_bins(n_1: int, n_2: int, m: int) -> np.ndarray:
    """``m x m`` directions inside each equal-solid-angle bin of ``(-w_z, atan2(w_y, w_x))`` below the layer."""
    sub = (np.arange(m) + 0.5) / m
    mu = (np.arange(n_1)[:, None] + sub[None, :]) / n_1
    phi = (np.arange(n_2)[:, None] + sub[None, :]) / n_2 * 2.0 * math.pi - math.pi
    mm = np.broadcast_to(mu[:, None, :, None], (n_1, n_2, m, m))
    pp = np.broadcast_to(phi[None, :, None, :], (n_1, n_2, m, m))
    s = np.sqrt(1.0 - mm ** 2)
    return np.stack([s * np.cos(pp), s * np.sin(pp), -mm], axis=-1).reshape(n_1, n_2, m * m, 3)


@pytest.mark.parametrize("beta_deg,spacing_ratio", [(0.0, 1.0), (50.0, 1.0), (50.0, 1.6)])
def test_down_operator_agrees_with_layer_trace(table, tracer, beta_deg, spacing_ratio):
    """P_down (volume) = the traced layer's light leaving DOWNWARDS past the neighbours, per bin of the lower
    hemisphere: the mirrored masking of the exit cells and the exit table's downward bins.

    Allowed: 4 standard errors of the trace + 4 % of the largest bin (as the upward layer test). The
    gap of the sparse layer (1.6) is not in either (the trace drops the photons that miss every fiber).
    """
    w_in = _w(0.3, beta_deg)
    n_1, n_2, n = 4, 8, 300_000
    sums, sq = tracer(n, 22, *w_in, R_UM, N_HOST, MU_S, MU_A, G, 2.0 * spacing_ratio * R_UM, n_1, n_2, True)
    omega = 2.0 * math.pi / (n_1 * n_2)
    mean = sums / n                                   # fraction of the incident power per bin
    trace = mean / omega
    u_trace = np.sqrt(np.maximum(sq / n - mean ** 2, 0.0) / (n - 1)) / omega
    dirs = _lower_bins(n_1, n_2, 5)
    got = AD.down_operator(table, _fiber(), w_in, dirs.reshape(-1, 3), spacing_ratio, surface=False)[:, 0]
    got = got.reshape(n_1, n_2, -1).mean(axis=2)
    assert trace.sum() * omega > 0.05                 # a real transmission is compared
    assert np.all(np.abs(got - trace) <= 4.0 * u_trace + 0.04 * trace.max()), (got, trace)


def test_down_operator_energy_is_the_closures_downward_light(table):
    """The quadrature of P_down over the lower hemisphere = the closure's unmasked downward fraction d(w_i)
    (:func:`simulate.fabric.interior.layer_energy`: point visibility tests, no mirrored cells) within 5 %."""
    fiber = _fiber()
    h = AD.hemisphere()
    for spacing_ratio in (1.0, 1.6):
        classes = IN.exit_classes(table, 2.0 * spacing_ratio)
        for w_in in (_w(0.0, 0.0), _w(0.3, 50.0), _w(0.6, 20.0)):
            d = IN.layer_energy(table, fiber, w_in, classes, spacing_ratio=spacing_ratio)[1, 0]
            p = AD.down_operator(table, fiber, w_in, h.w * AD.FLIP_Z, spacing_ratio)[:, 0].sum() * h.d_omega
            assert p == pytest.approx(d, rel=0.05)


def test_up_operator_mirror_bookkeeping(table):
    """up_operator's quadrant-and-mirrors route = P_down(M(-w) -> M w_o) computed directly, in every quadrant."""
    fiber = _fiber()
    h = AD.hemisphere(4, 8)
    adding = AD.Adding(h, 1.3)
    w_out = np.array([[0.3, -0.5, 0.0], [-0.6, 0.1, 0.0], [0.07, 0.13, 0.0]])   # off the bins' edges
    w_out[:, 2] = np.sqrt(1.0 - (w_out[:, :2] ** 2).sum(axis=1))
    up, t_up = adding.up_operator(table, fiber, w_out)
    for k in range(h.w.shape[0]):
        src = -h.w[k] * AD.FLIP_Z                      # M(-w)
        direct = AD.down_operator(table, fiber, src, w_out * AD.FLIP_Z, 1.3)
        np.testing.assert_allclose(up[k], direct, rtol=1e-9, atol=1e-14)
        total = AD.down_operator(table, fiber, src, h.w * AD.FLIP_Z, 1.3).sum(axis=0) * h.d_omega
        np.testing.assert_allclose(t_up[k], total + AD.gap_fraction(table, src[None], 1.3), rtol=1e-9)
    assert np.ptp(up[:, 0, 0]) > 0.1 * up[:, 0, 0].max()   # the directions differ: the test is not vacuous


def _albedo(lt: FL.LayerTable, w_in: np.ndarray, n_mu: int = 24, n_phi: int = 48) -> np.ndarray:
    """``int G(w_i, w_o) / (w_i . z) dw_o`` on a fine midpoint grid."""
    h = AD.hemisphere(n_mu, n_phi)
    g = lt(np.broadcast_to(w_in, h.w.shape), h.w)
    return g.sum(axis=0) * h.d_omega / w_in[2]


@pytest.mark.parametrize("spacing_ratio", [1.0, 2.2])
def test_directional_return_keeps_the_closures_energy(white, spacing_ratio):
    """A white fiber stack: the directional return sends back what the diffuse closure sends back, in total
    (it only moves the first order's light in angle), and it does move it (forward of the mirror)."""
    fiber, table = white
    diffuse = IN.interior(table, fiber, 10, spacing_ratio=spacing_ratio)
    directional = IN.interior(table, fiber, 10, spacing_ratio=spacing_ratio, directional=True)
    lt_d = FL.layer_table(table, fiber, spacing_ratio=spacing_ratio, interior=diffuse, step_deg=15.0, phi_step_deg=30.0)
    lt_a = FL.layer_table(table, fiber, spacing_ratio=spacing_ratio, interior=directional, step_deg=15.0,
                          phi_step_deg=30.0)
    for theta in (0.0, 30.0, 60.0):
        w_in = np.array([math.sin(math.radians(theta)) * math.cos(0.5), math.sin(math.radians(theta)) * math.sin(0.5),
                         math.cos(math.radians(theta))])
        a_d, a_a = _albedo(lt_d, w_in), _albedo(lt_a, w_in)
        assert 0.5 < a_d[0] < 1.0
        assert a_a[0] == pytest.approx(a_d[0], rel=0.01)
    # the shape changed: the returned light is no longer Lambertian
    diff = np.abs(lt_a.G - lt_d.G).max()
    assert diff > 0.02 * lt_d.G.max()


def test_resolved_first_order_is_the_closures_path(white):
    """Touching layers of a white fiber: the adding's energy of the first order, E_D, is the closure's estimate
    of the same path, C = X_u r t, to the angular correlation it averages out (within 15 %), and less than the
    light the top layer sends down."""
    fiber, table = white
    inner = IN.interior(table, fiber, 10, directional=True)
    single = FL.layer_table(table, fiber)
    h = AD.hemisphere()
    adding = AD.Adding(h, 1.0)
    up = adding.up_operator(table, fiber, h.w)
    for theta in (0.0, 60.0):
        w_in = np.array([math.sin(math.radians(theta)) * math.cos(0.3), math.sin(math.radians(theta)) * math.sin(0.3),
                         math.cos(math.radians(theta))])
        energy = IN.layer_energy(table, fiber, w_in, inner.classes)
        down = AD.down_operator(table, fiber, w_in, h.w * AD.FLIP_Z, 1.0)
        D, E = adding.term(table, fiber, single, w_in[None], down[None], h.w, up)
        assert D[0].sum(axis=0)[0] * h.d_omega == pytest.approx(E[0, 0], rel=0.03)   # the operators' totals
        assert E[0, 0] == pytest.approx(inner.first_order(energy)[0], rel=0.15)
        assert E[0, 0] < energy[1, 0] + energy[3, 0]
