"""Turned traces in one wavefront (simulate.raytrace.trace_rotations, the felt's azimuths).

Each rotation's rays share every bounce's Embree query with the other rotations' and must still
score as that rotation's own trace would: compared with separate traces of the turned incidence and
detectors within a few reported standard errors (fixed seeds), on a plain weave, which is not
isotropic in its plane, so a rotation scored towards detectors not turned with it would show.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulate import fiber as F
from simulate import raytrace as W
from simulate.geometry import weave
from simulate.geometry.mesh import mesh as weave_mesh
from simulate.media.medium import HGMedium
from simulate.raytrace.integrator import trace_rotations


def _dirs(theta_deg, phi_deg=0.0):
    t = np.radians(np.atleast_1d(theta_deg))
    p = np.radians(np.broadcast_to(phi_deg, t.shape))
    return np.column_stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def _rot(a):
    return np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def case():
    fib = F.Fiber(10.0, 1.5, HGMedium(mu_s=0.8, mu_a=0.01, g=0.5), 0.3, 10.0)
    table = W.yarn_table(fib, [550.0], photons_per_row=4000, seed=12, threads=1)
    plain = weave.Weave(np.array([[1, 0], [0, 1]]), spacing_um=300.0, width_um=250.0, height_um=100.0,
                        points_per_span=6, sides=12)
    return weave_mesh(plain), W.FiberSurface(table, 0.35, 1.5)


ANGLES = [0.0, math.radians(45.0), math.radians(200.0)]
W_IN = _dirs(60.0, 10.0)[0]
DET = _dirs([0.0, 30.0, 60.0, 60.0, 45.0], [0.0, 190.0, 10.0, 100.0, 280.0])


def test_each_rotation_of_a_joint_trace_is_its_turned_trace(case):
    mesh, mat = case
    joint = trace_rotations(mesh, mat, W_IN, DET, ANGLES, target_rel_err=1e-9, max_rays=3 * 16384, seed=3,
                            chunk=1024)
    assert [r.rays for r in joint] == [16384] * 3 and all(r.stop == "max_rays" for r in joint)
    alone = [W.trace(mesh, mat, _rot(a) @ W_IN, DET @ _rot(a).T, target_rel_err=1e-9, max_rays=16384, seed=40 + j,
                     chunk=1024) for j, a in enumerate(ANGLES)]
    for j in range(3):
        z = (joint[j].beta - alone[j].beta) / np.hypot(joint[j].u_beta, alone[j].u_beta)
        assert np.max(np.abs(z)) < 4.0, (j, z)
    # the test has power: a rotation's incidence scored towards unturned detectors is far off
    wrong = W.trace(mesh, mat, _rot(ANGLES[1]) @ W_IN, DET, target_rel_err=1e-9, max_rays=16384, seed=50, chunk=1024)
    z = (wrong.beta - alone[1].beta) / np.hypot(wrong.u_beta, alone[1].u_beta)
    assert float(np.sum(z ** 2)) > 40.0, z       # chi-square of 5 detectors: P(> 40) ~ 1e-7 when alike


def test_a_joint_trace_does_not_depend_on_the_threads(case):
    mesh, mat = case
    kw = dict(target_rel_err=0.03, seed=9, chunk=256)
    a = trace_rotations(mesh, mat, W_IN, DET, ANGLES, threads=1, **kw)
    b = trace_rotations(mesh, mat, W_IN, DET, ANGLES, threads=2, **kw)
    for ra, rb in zip(a, b, strict=True):
        np.testing.assert_array_equal(ra.beta, rb.beta)
        np.testing.assert_array_equal(ra.u_beta, rb.u_beta)
        assert ra.rays == rb.rays


def test_a_joint_trace_stops_on_the_mean_of_its_rotations(case):
    """The mean over the rotations reaches the target, the last round cut to what it still needed
    (fewer rays than whole rounds of full chunks), and a ray budget is kept exactly."""
    mesh, mat = case
    res = trace_rotations(mesh, mat, W_IN, DET, ANGLES, target_rel_err=0.008, seed=5, chunk=512)
    mean = np.mean([r.beta for r in res], axis=0)
    u = np.sqrt(np.sum([r.u_beta ** 2 for r in res], axis=0)) / len(res)
    assert all(r.stop == "target" for r in res)
    assert W.estimate.relative_error(mean, u) <= 0.008
    assert res[0].rays % (4 * 512) != 0          # the last round held less than full chunks
    over = trace_rotations(mesh, mat, W_IN, DET, ANGLES, target_rel_err=1e-6, max_rays=3 * 3000, seed=5, chunk=512)
    assert all(r.stop == "max_rays" and r.rays == 3000 for r in over)
    with pytest.raises(ValueError, match="at least one angle"):
        trace_rotations(mesh, mat, W_IN, DET, [])


def test_a_joint_traces_reported_error_matches_its_spread_over_seeds(case):
    """Short joint traces at 16 seeds against one long one: about 68 % of the rotations' mean within
    one reported standard error (the rotations of a chunk share its random stream, not its draws)."""
    mesh, mat = case
    det = DET[:3]

    def mean_of(res):
        return (np.mean([r.beta for r in res], axis=0),
                np.sqrt(np.sum([r.u_beta ** 2 for r in res], axis=0)) / len(res))

    ref, u_ref = mean_of(trace_rotations(mesh, mat, W_IN, det, ANGLES, target_rel_err=1e-9, max_rays=3 * 32768,
                                         seed=100, chunk=2048))
    inside = []
    for k in range(16):
        b, u = mean_of(trace_rotations(mesh, mat, W_IN, det, ANGLES, target_rel_err=1e-9, max_rays=3 * 2048,
                                       seed=200 + k, chunk=512))
        inside += list((np.abs(b - ref) <= np.hypot(u, u_ref)).ravel())
    frac = float(np.mean(inside))
    spread = 3 * math.sqrt(0.6827 * 0.3173 / (len(inside) / 3))   # a run's detectors are correlated: n / 3
    assert abs(frac - 0.6827) < spread, (frac, spread)
