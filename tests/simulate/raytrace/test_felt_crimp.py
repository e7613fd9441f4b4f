"""Crimped fibers in the felt: the sine axis of each fiber, its deposition, and today's felt at crimp 0."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest
from scipy.integrate import quad

from simulate import fabric as fab
from simulate import raytrace as W
from simulate.fabric import structure as ST
from simulate.geometry import felt
from simulate.geometry.felt import crimp_amplitude, felt_mesh


def _spec(**kw):
    return ST.StructureSpec(kind="nonwoven", layers=4, **kw)


def _arc(A: float, lam: float, phase: float, x0: float, x1: float) -> float:
    """Arc length of ``A sin(2 pi x / lam + phase)`` from ``x0`` to ``x1`` (quadrature, not the code's sums)."""
    k = 2 * math.pi / lam
    return quad(lambda x: math.sqrt(1 + (A * k * math.cos(k * x + phase)) ** 2), x0, x1, epsabs=1e-12,
                epsrel=1e-12, limit=200)[0]


def test_crimp_zero_is_todays_felt_bit_for_bit():
    """At crimp 0 nothing more is drawn from the stream, whatever the other crimp fields: the same felt."""
    plain = felt_mesh(_spec(), 10.0, seed=3)
    zero = felt_mesh(_spec(felt_crimp_percent=0.0, felt_crimp_per_cm=15.0, felt_crimp_plane="random"), 10.0, seed=3)
    for name in ("vertices", "faces", "normals", "tangents", "vertex_s", "vertex_phi", "n_s"):
        assert np.array_equal(getattr(plain, name), getattr(zero, name)), name
    assert plain.info == zero.info and "crimp_amplitude_um" not in plain.info
    # and a crimp does change the felt (the test above is not vacuous)
    some = felt_mesh(_spec(felt_crimp_percent=13.0), 10.0, seed=3)
    assert some.info["crimp_amplitude_um"] > 0
    assert some.vertices.shape != plain.vertices.shape or not np.array_equal(some.vertices, plain.vertices)


@pytest.mark.parametrize("percent,per_cm", [(13.0, 4.4), (2.0, 10.0), (35.0, 1.0)])
def test_the_amplitude_gives_the_crimp_percentage(percent, per_cm):
    """(straightened - crimped) / straightened length of one wave is the crimp percentage."""
    lam = 1e4 / per_cm
    A = crimp_amplitude(percent, lam)
    straightened = _arc(A, lam, 0.0, 0.0, lam)
    assert abs((straightened - lam) / straightened - percent / 100) < 1e-9
    assert crimp_amplitude(0.0, lam) == 0.0


def test_a_crimped_tube_lies_on_its_sine_and_turns_as_it_does():
    R, ell, lam, phase, n_s, sides = 10.0, 400.0, 700.0, 2.0, 12, 16
    A = crimp_amplitude(25.0, lam)
    eps = math.radians(20.0)
    t = np.array([math.cos(eps) * math.cos(0.4), math.cos(eps) * math.sin(0.4), math.sin(eps)])
    d = np.cross([0.0, 0.0, 1.0], t)
    d /= np.linalg.norm(d)
    c = np.array([5.0, -3.0, 7.0])
    pts, nrm, tan, s, phi, _ = felt._crimped_tube(c, t, d, R, ell, A, lam, phase, n_s, sides)
    pts, nrm, tan = (a.reshape(n_s + 1, sides + 1, 3) for a in (pts, nrm, tan))
    centre = pts[:, :-1].mean(axis=1)                   # the rings' centres
    rel = centre - c
    x, y, off = rel @ t, rel @ d, rel @ np.cross(t, d)
    k = 2 * math.pi / lam
    # the centres are on the sine (the arc's midpoint at c), in the plane of t and d
    assert np.allclose(off, 0.0, atol=1e-9)
    assert np.allclose(y, A * (np.sin(k * x + phase) - math.sin(phase)), atol=1e-6 * A)
    assert abs(x[n_s // 2]) < 1e-9 and abs(y[n_s // 2]) < 1e-9
    # at uniform arc length along the sine, ell in all
    arcs = np.array([_arc(A, lam, phase, x[i], x[i + 1]) for i in range(n_s)])
    assert np.allclose(arcs, ell / n_s, rtol=1e-5)
    assert np.allclose(s.reshape(n_s + 1, sides + 1)[:, 0], np.linspace(0, ell, n_s + 1))
    # every vertex is R from the sine curve (its nearest point on a dense sampling of the curve)
    xs = np.linspace(x[0] - R, x[-1] + R, 200_001)
    curve = c + xs[:, None] * t + (A * (np.sin(k * xs + phase) - math.sin(phase)))[:, None] * d
    v = pts[:, :-1].reshape(-1, 3)
    dist = np.array([np.sqrt(((curve - p) ** 2).sum(axis=1)).min() for p in v])
    assert np.allclose(dist, R, rtol=1e-4)
    # the vertex tangents are the sine's: their angle to the run t is atan(dy/dx) at each ring
    slope = A * k * np.cos(k * x + phase)
    ang = np.arctan2(tan[:, 0] @ d, tan[:, 0] @ t)
    assert np.allclose(ang, np.arctan(slope), atol=1e-9)
    turn = np.degrees(ang[-1] - ang[0])
    assert abs(turn) > 10.0                             # a bent fiber (the test is not of a straight one)
    # normals radial, perpendicular to the tangent; the frame transported (phi continuous along the fiber)
    assert np.allclose(pts - centre[:, None, :] - R * nrm, 0.0, atol=1e-9)
    assert np.allclose(np.einsum("kji,kji->kj", nrm, tan), 0.0, atol=1e-12)
    step = np.einsum("kji,kji->kj", nrm[1:], nrm[:-1])
    assert np.all(step > np.cos(np.abs(np.diff(ang)) + 1e-3)[:, None])
    assert np.allclose(phi.reshape(n_s + 1, sides + 1)[0], 2 * np.pi * np.arange(sides + 1) / sides)


@pytest.mark.parametrize("plane", ["felt", "random"])
def test_crimped_fibers_do_not_interpenetrate(monkeypatch, plane):
    """A strong crimp (0.8 of a wave per fiber) deposited without overlaps (points on the pieces' cylinders
    inside no other fiber); with the contact rule switched off the same check finds them buried."""
    from fabric_optics.bench.felt import buried_fraction

    spec = _spec(felt_crimp_percent=30.0, felt_crimp_per_cm=20.0, felt_crimp_plane=plane, felt_spread_deg=10.0)
    m = felt_mesh(spec, 10.0, seed=4)
    assert m.info["pieces"] > 4 and m.info["crimp_plane"] == plane
    assert buried_fraction(m) == 0.0
    assert 0.03 < m.info["volume_fraction"] < 0.3
    monkeypatch.setattr(felt, "CONTACT", -1.0)
    assert buried_fraction(felt_mesh(spec, 10.0, seed=4)) > 0.05


def test_the_crimp_plane_keeps_or_tilts_the_pieces():
    """The plane "felt": fibers drawn in the plane stay in it (every vertex tangent horizontal); "random":
    the pieces tilt by up to the sine's slope."""
    flat = felt_mesh(_spec(felt_crimp_percent=20.0, felt_crimp_per_cm=10.0, felt_spread_deg=0.0), 10.0, seed=1)
    assert np.allclose(flat.tangents[:, 2], 0.0, atol=1e-12)
    turned = felt_mesh(_spec(felt_crimp_percent=20.0, felt_crimp_per_cm=10.0, felt_spread_deg=0.0,
                             felt_crimp_plane="random"), 10.0, seed=1)
    tilt = np.degrees(np.arcsin(np.abs(turned.tangents[:, 2])))
    A = turned.info["crimp_amplitude_um"]
    assert 10.0 < tilt.max() <= np.degrees(np.arctan(A * 2 * math.pi / turned.info["crimp_wavelength_um"])) + 1e-6


def test_the_tracer_runs_on_a_crimped_felt():
    m = felt_mesh(_spec(felt_crimp_percent=13.0), 10.0, seed=2)
    w_in, det = fab.directions_deg([30.0], [0.0])[0], fab.directions_deg([0.0, 30.0, 60.0], [0.0, 180.0, 90.0])
    r = W.trace(m, W.Lambert(0.8), w_in, det, target_rel_err=1e-9, max_rays=4096, seed=1, chunk=2048)
    assert np.all(np.isfinite(r.beta)) and np.all(r.beta > 0) and r.info["lost_rays"] == 0
    total = r.reflected + r.transmitted
    assert np.all(total <= 1.0 + 4 * np.hypot(r.u_reflected, r.u_transmitted))
    assert np.all(r.reflected > 0.2)


def test_the_summation_says_once_that_its_felt_has_no_crimp(monkeypatch, caplog):
    monkeypatch.setattr(ST, "_CRIMP_NOTED", [])
    with caplog.at_level(logging.WARNING, logger=ST.__name__):
        ST.felt_facets(_spec())
        assert not caplog.records
        ST.felt_facets(_spec(felt_crimp_percent=13.0))
        ST.felt_facets(_spec(felt_crimp_percent=13.0))
    assert len(caplog.records) == 1 and "felt_crimp_percent" in caplog.records[0].getMessage()
