"""The felt's loose top (``felt_fuzz_fraction``, ``felt_fuzz_depth_um``): its fibers above the compact felt
within the depth, no interpenetration, today's felt at fraction 0, and the fields' validation."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from simulate.config import ConfigError, parse_config
from simulate.fabric import structure as ST
from simulate.geometry import felt
from simulate.geometry.felt import felt_mesh, fiber_pieces
from simulate.geometry.mesh import FabricMesh
from simulate.montecarlo import ParameterError

R = 10.0


def _spec(**kw) -> ST.StructureSpec:
    return ST.StructureSpec(kind="nonwoven", layers=4, **kw)


def _same(a: FabricMesh, b: FabricMesh) -> bool:
    names = ("vertices", "faces", "normals", "tangents", "vertex_s", "vertex_phi", "n_s", "yarn_length")
    return all(getattr(a, n).shape == getattr(b, n).shape and np.array_equal(getattr(a, n), getattr(b, n))
               for n in names) and a.info == b.info


@pytest.mark.parametrize("kw", [{}, {"felt_crimp_percent": 13.0}, {"felt_normal_fraction": 0.3}],
                         ids=["straight", "crimped", "needled"])
def test_fraction_zero_is_todays_felt_bit_for_bit(kw):
    """At fraction 0 nothing more is drawn from the stream, whatever the depth: the same felt."""
    plain = felt_mesh(_spec(**kw), R, seed=3)
    zero = felt_mesh(_spec(felt_fuzz_fraction=0.0, felt_fuzz_depth_um=40.0, **kw), R, seed=3)
    assert _same(plain, zero) and "fuzz_fibers" not in plain.info
    # and a loose top does change the felt (the test above is not vacuous)
    some = felt_mesh(_spec(felt_fuzz_fraction=0.2, **kw), R, seed=3)
    assert some.info["fuzz_fibers"] > 0 and not _same(plain, some)


def test_a_fraction_below_one_fibre_draws_no_loose_fibre():
    """A fraction the last compact fiber's amount already covers: no loose fiber, the compact felt's top is the
    felt's, the geometry today's."""
    plain = felt_mesh(_spec(), R, seed=3)
    tiny = felt_mesh(_spec(felt_fuzz_fraction=1e-4), R, seed=3)
    assert tiny.info["fuzz_fibers"] == 0 and tiny.info["compact_top_um"] == 0.0
    assert np.array_equal(plain.vertices, tiny.vertices)


def _images(m: FabricMesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each fiber image's lowest and highest point (its axis's, less and plus the radius) and its tangent."""
    p0, pd = fiber_pieces(m)
    z = np.concatenate([p0[:, :, 2], p0[:, -1:, 2] + pd[:, -1:, 2]], axis=1)
    return z.min(axis=1) - R, z.max(axis=1) + R, m.tangents[m.vertex_base]


@pytest.mark.parametrize("kw", [{}, {"felt_crimp_percent": 20.0, "felt_crimp_plane": "random"}],
                         ids=["straight", "crimped"])
def test_the_loose_fibers_lie_above_the_compact_top_within_the_depth(kw):
    depth = 300.0
    m = felt_mesh(_spec(felt_fuzz_fraction=0.3, felt_fuzz_depth_um=depth, felt_spread_deg=10.0, **kw), R, seed=5)
    info = m.info
    top = info["compact_top_um"]                  # the compact felt's top (the felt's top is z = 0)
    low, high, tangent = _images(m)
    loose = low >= top - 1e-6
    # every image is the compact felt's (wholly below its top) or a loose one (wholly above it) ...
    assert np.all(high[~loose] <= top + 1e-6)
    # ... the loose ones are the loose fibers' images (a fiber's images share its tangent) ...
    n_loose = len(np.unique(np.round(tangent[loose], 12), axis=0))
    assert n_loose == info["fuzz_fibers"] > 5
    assert info["fibers"] - info["fuzz_fibers"] == len(np.unique(np.round(tangent[~loose], 12), axis=0))
    # ... with their lowest points within the depth, spread over it (not stacked at its bottom)
    assert np.all(low[loose] <= top + depth + 1e-6)
    assert np.ptp(low[loose]) > 0.5 * depth
    assert abs(high.max()) < 1e-6 and high[loose].max() == high.max()   # the felt's top (z = 0) is a loose fiber's
    # the fraction is of the fiber amount: loose fibers' projected area over the whole felt's
    assert 0.2 < info["fuzz_fibers"] / info["fibers"] < 0.4


@pytest.mark.parametrize("kw", [{}, {"felt_crimp_percent": 30.0, "felt_crimp_per_cm": 20.0}],
                         ids=["straight", "crimped"])
def test_loose_fibers_do_not_interpenetrate(monkeypatch, kw):
    """A dense loose top (the fraction 0.4 in 300 um: fibers raised by the ones placed before) deposited
    without overlaps; with the contact rule switched off the same check finds fibers buried."""
    from fabric_optics.bench.felt import buried_fraction

    spec = _spec(felt_fuzz_fraction=0.4, felt_fuzz_depth_um=300.0, felt_spread_deg=10.0, **kw)
    m = felt_mesh(spec, R, seed=2)
    assert m.info["fuzz_fibers"] > 10
    assert buried_fraction(m) == 0.0
    monkeypatch.setattr(felt, "CONTACT", -1.0)
    assert buried_fraction(felt_mesh(spec, R, seed=2)) > 0.02


def test_a_depth_too_thin_for_the_loose_fibers_is_refused_by_name(monkeypatch):
    monkeypatch.setattr(felt, "LOOSE_TRIES", 50)
    with pytest.raises(ParameterError, match=r"^\[structure\] felt_fuzz_depth_um = 5: .*raise felt_fuzz_depth_um"):
        felt_mesh(_spec(felt_fuzz_fraction=0.5, felt_fuzz_depth_um=5.0), R, seed=1)


def test_the_key_and_the_walk_follow_the_fields():
    """Both fields are felt inputs (the table cache's key); the summation's walk leaves them out (Monte Carlo
    only)."""
    base = felt.felt_key(_spec(), R, seed=1)
    assert felt.felt_key(_spec(felt_fuzz_fraction=0.1), R, seed=1) != base
    assert felt.felt_key(_spec(felt_fuzz_depth_um=200.0), R, seed=1) != base
    assert {"felt_fuzz_fraction", "felt_fuzz_depth_um"} <= set(ST.FELT_ONLY_KEYS)


def test_the_summation_says_once_that_its_felt_has_no_loose_top(monkeypatch, caplog):
    monkeypatch.setattr(ST, "_FUZZ_NOTED", [])
    with caplog.at_level(logging.WARNING, logger=ST.__name__):
        ST.felt_facets(_spec())
        assert not caplog.records
        ST.felt_facets(_spec(felt_fuzz_fraction=0.2))
        ST.felt_facets(_spec(felt_fuzz_fraction=0.2))
    assert len(caplog.records) == 1 and "felt_fuzz_fraction" in caplog.records[0].getMessage()


CONFIG = """
name = "fuzz"
[fiber]
radius_um = 10.0
n_host = 1.5
[medium]
mu_s = 0.4
mu_a = 0.02
g = 0.5
[surface]
rms_slope = 0.3
[structure]
"""


@pytest.mark.parametrize("line,field", [
    ('kind = "nonwoven"\nfelt_fuzz_fraction = 0.6', "structure.felt_fuzz_fraction"),
    ('kind = "nonwoven"\nfelt_fuzz_fraction = -0.1', "structure.felt_fuzz_fraction"),
    ('kind = "nonwoven"\nfelt_fuzz_fraction = "some"', "structure.felt_fuzz_fraction"),
    ('kind = "nonwoven"\nfelt_fuzz_depth_um = 0', "structure.felt_fuzz_depth_um"),
    ('kind = "nonwoven"\nfelt_fuzz_depth_um = 6000', "structure.felt_fuzz_depth_um"),
    ('kind = "nonwoven"\nfelt_fuzz_depth_um = nan', "structure.felt_fuzz_depth_um"),
    ('felt_fuzz_fraction = 0.1', "structure.felt_fuzz_fraction"),
    ('felt_fuzz_depth_um = 100', "structure.felt_fuzz_depth_um"),
])
def test_bad_fields_are_refused_by_name(line, field):
    with pytest.raises(ConfigError) as exc:
        parse_config(CONFIG + line + "\n", "bad.toml")
    message = str(exc.value)
    assert message.startswith(f"bad.toml: {field}") and "\n" not in message


def test_the_fields_are_read():
    cfg = parse_config(CONFIG + 'kind = "nonwoven"\nfelt_fuzz_fraction = 0.25\nfelt_fuzz_depth_um = 450\n', "ok.toml")
    assert (cfg.structure.felt_fuzz_fraction, cfg.structure.felt_fuzz_depth_um) == (0.25, 450.0)


@pytest.mark.parametrize("line,field", [("felt_fuzz_fraction = 0.7", "structure.felt_fuzz_fraction"),
                                        ("felt_fuzz_depth_um = -3", "structure.felt_fuzz_depth_um")])
def test_a_bad_field_is_one_line_exit_2(tmp_path, capsys, line, field):
    from fabric_optics.cli.simulate import main

    path = tmp_path / "bad.toml"
    path.write_text(CONFIG + 'kind = "nonwoven"\n' + line + "\n")
    assert main(["fabric", str(path), "--method", "mc", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and field in err[0]
    assert not (tmp_path / "o").exists()
