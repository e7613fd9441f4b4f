"""The needle-punched felt: a population of fibers towards the normal; at fraction 0 today's felt."""

from __future__ import annotations

import math

import numpy as np

from simulate.fabric import structure as ST
from simulate.geometry.felt import felt_mesh


def _fibers(m):
    """One tangent per fiber (its first image), and whether each image is its fiber's first."""
    return m.tangents[m.vertex_base]


def test_fraction_zero_is_todays_felt_bit_for_bit():
    """At fraction 0 nothing more is drawn from the stream, whatever the tilt spread: the same mesh."""
    plain = felt_mesh(ST.StructureSpec(kind="nonwoven", layers=4), 10.0, seed=3)
    zero = felt_mesh(ST.StructureSpec(kind="nonwoven", layers=4, felt_normal_fraction=0.0,
                                      felt_normal_spread_deg=40.0), 10.0, seed=3)
    assert np.array_equal(plain.vertices, zero.vertices) and np.array_equal(plain.faces, zero.faces)
    assert plain.info["normal_fibers"] == zero.info["normal_fibers"] == 0
    # and a non-zero fraction does change the felt (the test above is not vacuous)
    some = felt_mesh(ST.StructureSpec(kind="nonwoven", layers=4, felt_normal_fraction=0.3), 10.0, seed=3)
    assert some.info["normal_fibers"] > 0
    assert some.vertices.shape != plain.vertices.shape or not np.array_equal(some.vertices, plain.vertices)


def test_the_punched_population_has_its_fraction_and_tilt():
    frac, tilt_sd = 0.3, 15.0
    spec = ST.StructureSpec(kind="nonwoven", layers=6, felt_spread_deg=5.0, felt_normal_fraction=frac,
                            felt_normal_spread_deg=tilt_sd)
    counts, tilts, azs = [], [], []
    for seed in range(3):
        m = felt_mesh(spec, 10.0, seed=seed)
        n, k = m.info["fibers"], m.info["normal_fibers"]
        counts.append((n, k))
        # fiber images of one fiber share its tangent: take the distinct directions
        t = np.unique(np.round(_fibers(m), 12), axis=0)
        up = t[np.abs(t[:, 2]) > math.sin(math.radians(30.0))]
        assert len(up) == k       # 30 deg from the plane: 6 sd of the in-plane population, 4 of the punched one
        tilts.append(np.degrees(np.arccos(np.abs(up[:, 2]))))
        azs.append(np.arctan2(up[:, 1] * np.sign(up[:, 2]), up[:, 0] * np.sign(up[:, 2])))
    n = sum(c[0] for c in counts)
    k = sum(c[1] for c in counts)
    # the draw is Bernoulli(frac) per fiber: within 4 binomial standard errors
    assert abs(k / n - frac) < 4 * math.sqrt(frac * (1 - frac) / n)
    tilt = np.concatenate(tilts)
    # |N(0, sd)|: RMS = sd, within 4 standard errors of the RMS (sd / sqrt(2 k))
    assert abs(math.sqrt(np.mean(tilt ** 2)) - tilt_sd) < 4 * tilt_sd / math.sqrt(2 * tilt.size)
    # the tilt's azimuth covers the full circle (not only [0, 180)): both half-planes hold tilts
    az = np.concatenate(azs)
    assert np.mean(az > 0) > 0.2 and np.mean(az < 0) > 0.2


def test_punched_fibers_do_not_interpenetrate():
    from fabric_optics.bench.felt import buried_fraction

    spec = ST.StructureSpec(kind="nonwoven", layers=4, felt_normal_fraction=0.4)
    assert buried_fraction(felt_mesh(spec, 10.0, seed=2)) == 0.0
