"""The opposition and mirror-to-neighbours ratios on synthetic datasets whose ratios are known."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from compare import ratios
from compare.comparison import compare_datasets
from gonio.data import in_plane_geometry

from .conftest import dataset, in_plane_table

WL = np.arange(450.0, 651.0, 20.0)          # 20 nm steps: the colour match needs them


def retro_angle(theta_i, theta_o, phi_o):
    """Angle between w_o and the retro direction (phi_i = 0), degrees: an independent formula
    (spherical law of cosines)."""
    ti, to, po = (np.radians(np.asarray(x, float)) for x in (theta_i, theta_o, phi_o))
    c = np.cos(ti) * np.cos(to) + np.sin(ti) * np.sin(to) * np.cos(po)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def peak(gamma, wl):
    """A ring-symmetric retro peak whose height depends on the wavelength."""
    return 1.0 + (wl / 1000.0) * np.exp(-(gamma / 10.0) ** 2)


def ring_table(incidences=(27.76, 40.03), n=12, keep=lambda psi: True, u=0.0):
    rows = []
    for ti in incidences:
        for rho in (ratios.INNER_DEG, ratios.OUTER_DEG):
            for k, (t, p) in enumerate(ratios.ring_directions(ti, rho, n)):
                if not keep(360.0 * k / n):
                    continue
                for wl in WL:
                    rows.append(dict(theta_i=ti, phi_i=0.0, theta_o=t, phi_o=p, wavelength_nm=wl))
    t = pd.DataFrame(rows)
    t["beta"] = peak(retro_angle(t.theta_i, t.theta_o, t.phi_o), t.wavelength_nm)
    t["u_beta"] = u
    return t


def test_ring_directions_lie_on_the_ring():
    for ti, rho in ((27.76, 6.0), (40.03, 30.0), (59.52, 30.0)):
        d = ratios.ring_directions(ti, rho, 24)
        gam = retro_angle(ti, [t for t, _ in d], [p for _, p in d])
        assert np.allclose(gam, rho, atol=1e-9)
        assert all(t < 90.0 for t, _ in d)
    assert len(ratios.ring_directions(59.52, 40.0, 24)) < 24       # the part below the horizon left out


def test_opposition_ratio_of_a_known_retro_peak():
    r = ratios.opposition_ratios(ring_table())
    assert set(r) == {27.76, 40.03}
    for ratio in r.values():
        assert ratio.n_points == (12, 12)
        for wl in WL:
            want = peak(6.0, wl) / peak(30.0, wl)
            assert math.isclose(ratio.value[wl], want, rel_tol=1e-12)
    # wavelength-dependent: the ratio grows with the peak's height
    assert r[40.03].value[650.0] > r[40.03].value[550.0] > r[40.03].value[450.0]


def test_opposition_uncertainty_is_propagated():
    u = 0.01
    r = ratios.opposition_ratios(ring_table(u=u))[40.03]
    m6, m30 = peak(6.0, 550.0), peak(30.0, 550.0)
    want = (m6 / m30) * math.hypot(u / math.sqrt(12) / m6, u / math.sqrt(12) / m30)
    assert math.isclose(r.u[550.0], want, rel_tol=1e-9)


def test_a_one_sided_ring_or_an_in_plane_curve_gives_no_opposition_ratio():
    one_side = ratios.opposition_ratios(ring_table(keep=lambda psi: psi <= 90.0))
    assert isinstance(one_side, ratios.Missing) and "one side" in one_side.reason
    plane = in_plane_table(lambda ti, s, wl: 1.0 + 0 * s)
    missing = ratios.opposition_ratios(plane)
    assert isinstance(missing, ratios.Missing) and "ring" in missing.reason
    # the in-plane curve at 30 deg has two points 30 deg from retro (s = 0 and -60): not a ring
    assert "30 deg: 0 point(s) on the ring at 6 deg" in missing.reason


def test_mirror_ratio_of_a_known_lobe():
    B = 0.8

    def beta(ti, s, wl):
        return 1.0 + B * (wl / 650.0) * np.exp(-((s - ti) / 5.0) ** 2)

    t = in_plane_table(beta, s_grid=np.arange(-60.0, 71.0, 5.0), wavelengths=WL)
    r = ratios.mirror_ratios(t)
    # mirror at s = theta_i needs a grid point: 30 and 60 only (45 too: step 5), not 0
    assert set(r) == {30.0, 45.0, 60.0}
    for ti in r:
        for wl in WL:
            b = B * wl / 650.0
            want = (1.0 + b) / (1.0 + b * math.exp(-4.0))   # neighbours at +-10 (the nearest 10)
            assert math.isclose(r[ti].value[wl], want, rel_tol=1e-12)
        assert r[ti].n_points == (1, 2)


def test_mirror_ratio_missing_when_no_mirror_point():
    t = in_plane_table(lambda ti, s, wl: 1.0 + 0 * s, incidence=(0.0, 45.0))
    m = ratios.mirror_ratios(t)
    assert isinstance(m, ratios.Missing) and "45 deg: no in-plane point at the mirror direction" in m.reason


def test_metrics_json_carries_the_ratios_and_they_ignore_the_normalisation():
    """A simulation that is the measurement times 3.7 (x a spectral factor) has the measurement's
    ratios exactly; a flat simulation has ratio 1; an in-plane-only one says why it has none."""
    rings = ring_table(incidences=(40.03,))
    normal = []
    for s in (-20.0, -10.0, 10.0, 20.0):                    # for the normal/normal estimate
        th, ph = in_plane_geometry(0.0, s, 0.0)
        for wl in WL:
            normal.append(dict(theta_i=0.0, phi_i=0.0, theta_o=th, phi_o=ph, wavelength_nm=wl,
                               beta=1.0, u_beta=0.0))
    table = pd.concat([rings, pd.DataFrame(normal)], ignore_index=True)
    table["n"] = 10
    meas = dataset(table)
    scaled = dataset(table.assign(beta=table.beta * 3.7 * table.wavelength_nm / 500.0), "simulated", "scaled")
    flat = dataset(table.assign(beta=1.0), "simulated", "flat")
    c = compare_datasets(meas, [scaled, flat])
    doc = c.metrics()["shape"]
    assert set(doc) == {"measured", "scaled", "flat"}
    m = doc["measured"]["opposition"]["per_incidence"]["40.03"]["value"]
    s = doc["scaled"]["opposition"]["per_incidence"]["40.03"]["value"]
    assert m.keys() == s.keys() == {f"{w:g}" for w in WL}
    for k in m:
        assert math.isclose(m[k], s[k], rel_tol=1e-12) and m[k] > 1.05
        assert doc["flat"]["opposition"]["per_incidence"]["40.03"]["value"][k] == 1.0
    assert "reason" in doc["measured"]["mirror"]


def test_a_ring_sampled_densely_on_one_side_is_averaged_over_its_azimuth():
    """beta rises linearly across the ring (cos of the azimuth about retro): 12 even points average
    to the centre value; 6 extra points on the high side must not move the ratio."""
    def lopsided(t):
        ti = t.theta_i.to_numpy()
        w_o = ratios._unit(t.theta_o.to_numpy(), t.phi_o.to_numpy())
        w_r, e1, _ = ratios._retro_frame(ti, 0.0 * ti)
        return 1.0 + 0.5 * np.einsum("ij,ij->i", w_o, e1)   # linear in cos(psi) on each ring

    even = ring_table(incidences=(40.03,))
    even["beta"] = lopsided(even)
    extra = []
    for rho in (ratios.INNER_DEG, ratios.OUTER_DEG):
        for t, p in ratios.ring_directions(40.03, rho, 72)[:6]:      # psi 0-25 deg: the high side
            extra += [dict(theta_i=40.03, phi_i=0.0, theta_o=t, phi_o=p, wavelength_nm=w, u_beta=0.0)
                      for w in WL]
    extra = pd.DataFrame(extra)
    extra["beta"] = lopsided(extra)
    dense = pd.concat([even, extra], ignore_index=True)
    a = ratios.opposition_ratios(even)[40.03].value[550.0]
    b = ratios.opposition_ratios(dense)[40.03].value[550.0]
    assert math.isclose(a, 1.0, abs_tol=1e-12)                 # both rings average to beta(retro) = 1
    assert abs(b - a) < 0.02 * 0.5 * (math.sin(math.radians(30)) - math.sin(math.radians(6)))
