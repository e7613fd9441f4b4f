"""An absorption table of a ring or core dye: its nodes are the dye's absorption in the dyed region. Read at a dye,
it is the fiber Monte Carlo of the fiber with that ring dye (within standard errors, independent seeds), and for a
clear fiber with an absorbing shell (or core) it is the closed form of straight chords through the annulus."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from simulate.config import load_config
from simulate.config_dye import DyeSpectrum
from simulate.fiber import Fiber, range_outputs, volume_brdf
from simulate.fiber.absorption import absorption_nodes, absorption_table
from simulate.media.medium import HGMedium
from simulate.montecarlo.transport import ParameterError


def _fresnel(cos_i: np.ndarray, n1: float, n2: float) -> np.ndarray:
    """Unpolarised Fresnel reflectance from the textbook amplitudes (Born & Wolf 1.5.21)."""
    c = np.clip(np.abs(cos_i), 0.0, 1.0)
    sin2_t = (n1 / n2) ** 2 * (1.0 - c * c)
    ct = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    rs = ((n1 * c - n2 * ct) / (n1 * c + n2 * ct)) ** 2
    rp = ((n2 * c - n1 * ct) / (n2 * c + n1 * ct)) ** 2
    return np.where(sin2_t >= 1.0, 1.0, 0.5 * (rs + rp))


def _annulus(n: float, mu: float, a: float, kind: str, m: int = 400_000) -> float:
    """Perpendicular incidence on a clear unit cylinder: a ray of impact parameter ``b`` refracts to ``sin t = b / n``
    and every chord inside (internal reflections included) keeps the distance ``|b| / n`` from the axis, crossing
    the inner circle of radius ``a`` over ``2 sqrt(a^2 - d^2)``; the exit fraction is ``(1 - F)^2 A / (1 - F A)``
    with ``A = exp(-mu L_dyed)``, averaged over ``b``."""
    b = (np.arange(m) + 0.5) / m * 2.0 - 1.0
    f = _fresnel(np.sqrt(1.0 - b * b), 1.0, n)
    d = np.abs(b) / n
    chord = 2.0 * np.sqrt(1.0 - d * d)
    inner = 2.0 * np.sqrt(np.clip(a * a - d * d, 0.0, None))
    dyed = chord - inner if kind == "ring" else inner
    A = np.exp(-mu * dyed)
    return float(np.mean((1.0 - f) ** 2 * A / (1.0 - f * A)))


@pytest.mark.parametrize("kind, depth", [("ring", 0.2), ("core", 0.4)])
def test_a_clear_fiber_with_an_absorbing_shell_or_core_is_the_annulus_closed_form(kind, depth):
    """Twelve cells around the fiber (30 deg each) take every exit; their binned volume terms times the projected
    solid angle of a cell's hemisphere (pi) over the route's scale (the cell's width over the beam's, 1 / half
    width) add up to the exited fraction, read at two nodes of the table."""
    fib = Fiber(radius_um=1.0, n_host=1.5, medium=HGMedium(mu_s=1e-9, mu_a=0.0, g=0.0), roughness=0.3,
                cell_width_deg=30.0, dye_profile=kind, dye_depth_um=depth)
    hw = fib.half_width
    outputs = np.vstack([range_outputs([0.0], [1.0], [-math.pi], [math.pi], hw, psi)
                         for psi in np.arange(12) * 2.0 * math.pi / 12])
    w_in = np.repeat([[0.0, 0.0, 1.0]], 12, axis=0)
    table = absorption_table(fib, w_in, outputs, [550.0], absorption_nodes(4.0), method="beam", target_rel_err=0.01,
                             seed=3)
    for node in (11, 14):                          # 0.24 and 1.97 /um: read at the nodes, no interpolation
        mu = table.nodes[node]
        R, u = table(np.array([mu]))
        exited = float(R[:, 0].sum() * math.pi * hw)
        u_exited = float(np.sqrt(np.sum(u[:, 0] ** 2)) * math.pi * hw)
        expected = _annulus(1.5, mu, 1.0 - depth, kind)
        assert abs(exited - expected) < 4.0 * u_exited, (kind, mu, exited, expected, u_exited)
        # the placement matters: the same dye through the whole fiber lets visibly less out
        assert exited > _annulus(1.5, mu, 0.0, "ring") + 20.0 * u_exited


def _ring_felt(wl: np.ndarray):
    """The green felt's fiber (smooth boundary) with a ring dye 1.5 um deep: three times the preset's dye at 450,
    550 and 650 nm (1.2, 0.029, 0.070 /um)."""
    cfg = load_config("green-felt-mc")
    mu = cfg.dye(wl) * 3.0
    dye = DyeSpectrum("table", {"wavelength_nm": [400.0, *wl, 700.0], "mu_a_per_um": [mu[0], *mu, mu[-1]]})
    return dataclasses.replace(cfg, dye=dye, dye_profile="ring", dye_depth_um=1.5, transmission_rms_slope=0.0,
                               transmission_rms_slope_around=None)


def test_a_ring_dyes_table_is_the_fiber_monte_carlo_with_the_ring_dye():
    """The table walked white (the undyed fiber keeps its ring), read at the dye, against the fiber Monte Carlo of
    the dyed fiber (its own seed): two exit ranges of an oblique beam, within 4 standard errors; the uniform dye of
    the same coefficient is told apart."""
    wl = np.array([450.0, 550.0, 650.0])
    cfg = _ring_felt(wl)
    w_in = np.repeat([[0.0, 0.6, 0.8]], 2, axis=0)
    undyed = cfg.undyed().fiber(wl)
    assert (undyed.dye_profile, undyed.dye_depth_um) == ("ring", 1.5)
    outputs = range_outputs([0.0, 0.5], [0.5, 1.0], [-math.pi, -math.pi], [math.pi, math.pi], undyed.half_width)
    table = absorption_table(undyed, w_in, outputs, wl, absorption_nodes(2.0), method="beam", target_rel_err=0.03,
                             seed=5)
    R, u = table(cfg.dye(wl))
    traced = volume_brdf(cfg.fiber(wl), w_in, None, wl, method="beam", outputs=outputs, target_rel_err=0.03, seed=6)
    z = (R - traced.R) / np.hypot(u, traced.u_R)
    assert np.all(np.abs(z) < 4.0), z
    uniform = volume_brdf(dataclasses.replace(cfg, dye_profile="uniform").fiber(wl), w_in, None, wl, method="beam",
                          outputs=outputs, target_rel_err=0.03, seed=6)
    assert np.all(R[:, 1:] > uniform.R[:, 1:] + 5.0 * np.hypot(u[:, 1:], uniform.u_R[:, 1:]))


def test_a_ring_dyes_table_refuses_the_next_event_route_and_a_reference_at_another_depth():
    wl = np.array([550.0])
    cfg = _ring_felt(np.array([450.0, 550.0, 650.0]))
    undyed = cfg.undyed().fiber(wl)
    w_in = np.array([[0.0, 0.6, 0.8]])
    point = np.array([[0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    with pytest.raises(ParameterError, match="a ring dye .* scored with exit tallies only; the nee route") as exc:
        absorption_table(undyed, w_in, point, wl, absorption_nodes(1.0), method="nee")
    assert "\n" not in str(exc.value)
    other = dataclasses.replace(undyed, dye_depth_um=2.0)
    outputs = range_outputs([0.0], [1.0], [-math.pi], [math.pi], undyed.half_width)
    with pytest.raises(ParameterError, match="the reference fiber's dye_profile and dye_depth_um must be the fiber's"):
        absorption_table(undyed, w_in, outputs, wl, absorption_nodes(1.0), method="beam", reference=other)
