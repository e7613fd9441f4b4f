"""The flattened-section screen (docs/scripts/fibre_section_screen.py): its ray optics against closed forms, and
the note's command on a tiny budget."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def screen():
    spec = importlib.util.spec_from_file_location("fibre_section_screen",
                                                  ROOT / "docs" / "scripts" / "fibre_section_screen.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["fibre_section_screen"] = module
    spec.loader.exec_module(module)
    return module


def _trace(screen, aspect, orientation, theta, *, n=1.51, mu_a=0.0, mu_s=0.0, g=0.0, slopes=(0.0, 0.0),
           rays=40_000, seed=3):
    return screen.trace(aspect, orientation, theta, radius_um=8.0, n_host=n, mu_a=mu_a, mu_s=mu_s, g=g,
                        reflect_slope=slopes[0], transmit_slope=slopes[1], rays=rays,
                        rng=np.random.default_rng(seed))


def test_fresnel_against_the_textbook_values(screen):
    n = 1.5
    assert screen.fresnel_unpolarised(np.array([1.0]), n)[0] == pytest.approx(((n - 1) / (n + 1)) ** 2, rel=1e-12)
    # Brewster's angle: the p reflectance vanishes, the unpolarised one is half the s one
    tb = np.arctan(n)
    tt = np.arcsin(np.sin(tb) / n)
    rs = (np.sin(tb - tt) / np.sin(tb + tt)) ** 2
    assert screen.fresnel_unpolarised(np.array([np.cos(tb)]), n)[0] == pytest.approx(rs / 2, rel=1e-9)
    # from inside beyond the critical angle: total internal reflection
    assert screen.fresnel_unpolarised(np.array([np.cos(np.radians(45.0))]), 1 / n)[0] == 1.0


@pytest.mark.parametrize("aspect,orientation", [(1.0, "flat"), (1.6, "flat"), (2.0, "random")])
def test_a_clear_section_loses_no_light(screen, aspect, orientation):
    res = _trace(screen, aspect, orientation, 27.0, slopes=(0.3, 0.1), mu_s=0.02, g=0.5)
    assert res["weight"].sum() / 40_000 == pytest.approx(1.0, abs=1e-9)


def test_an_index_matched_absorbing_ellipse_transmits_beer_lambert(screen):
    """With the host's index 1 nothing refracts or reflects: every ray crosses the flat ellipse straight down at
    normal incidence, through a chord 2 b sqrt(1 - (x / a)^2) at an offset x uniform over (-a, a)."""
    aspect, mu_a, r = 1.6, 0.05, 8.0
    a, b = r * np.sqrt(aspect), r / np.sqrt(aspect)
    expected = integrate.quad(lambda u: np.exp(-mu_a * 2 * b * np.sqrt(1 - u * u)), -1, 1)[0] / 2
    res = _trace(screen, aspect, "flat", 0.0, n=1.0, mu_a=mu_a)
    w = res["weight"] / 40_000
    per_ray = res["weight"]
    se = per_ray.std(ddof=1) / np.sqrt(per_ray.size)
    assert w.sum() == pytest.approx(expected, abs=4 * se)
    assert np.allclose(np.abs(res["angle"]), 180.0)           # straight through, downwards
    assert a > b                                               # the flat ellipse: its long axis in the felt's plane


def test_a_round_section_does_not_care_how_it_is_turned(screen):
    """The round section's forward rise is the same turned at random as lying flat (within their errors)."""
    flat = screen.forward_rise(_trace(screen, 1.0, "flat", 40.0, slopes=(0.3, 0.1), rays=60_000, seed=5))
    turned = screen.forward_rise(_trace(screen, 1.0, "random", 40.0, slopes=(0.3, 0.1), rays=60_000, seed=6))
    assert abs(flat[0] - turned[0]) < 4 * np.hypot(flat[1], turned[1])


def test_a_randomly_turned_section_scatters_the_same_at_every_incidence(screen):
    """Turned at random, the section has no preferred direction: its exits relative to the beam's direction are
    the same at 0 and 40 deg incidence (histograms within 4 standard errors per bin)."""
    hists = []
    for theta, seed in ((0.0, 7), (40.0, 8)):
        res = _trace(screen, 1.6, "random", theta, rays=60_000, seed=seed)
        rel = (res["angle"] - (180.0 - theta) + 180.0) % 360.0 - 180.0
        counts, _ = np.histogram(rel, bins=18, range=(-180, 180))
        hists.append(counts)
    a, b = (h.astype(float) for h in hists)
    assert np.all(np.abs(a - b) <= 4 * np.sqrt(a + b + 1))


def test_the_notes_command_runs_on_a_tiny_budget(screen, tmp_path):
    out = tmp_path / "screen.json"
    assert screen.main(["--rays", "400", "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    assert len(d["rows"]) == 2 * 2 * 4 * 4
    assert all(r["change"] == 0.0 for r in d["rows"] if r["aspect"] == 1.0)
    assert d["fibre"]["n_host"] == 1.51
    assert screen.main(["--rays", "5"]) == 2
