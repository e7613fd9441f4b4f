"""The cost check's Mie coefficients through the table cache: the same estimate, the same decision."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from simulate import budget
from simulate.config import load_config, preset_names
from simulate.fiber import tablecache
from simulate.optics import mie


def _events_computed(config, wavelengths) -> float:
    """The events per photon computed from the Mie cross sections every time (the reference)."""
    diameter = 2.0 * config.radius_um
    if config.hg is not None:
        props = [config.hg] * len(wavelengths)
    else:
        medium = config.medium(wavelengths)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ops = [medium.optical_properties(float(w), with_phase=False) for w in wavelengths]
        props = [(op.mu_s, op.mu_a, op.g) for op in ops]
    events = []
    for mu_s, mu_a, g in props:
        tau_s = mu_s * diameter
        tau_t = mu_s * (1.0 - g) * diameter
        mu_t = mu_s + mu_a
        absorbed = 10.0 / (mu_a / mu_t) if mu_t > 0 and mu_a > 0 else math.inf
        events.append(1.0 + min(tau_s * (1.0 + tau_t), absorbed, budget.EVENT_CAP))
    return float(np.mean(events))


def _estimate_computed(config, wavelengths, target, max_photons=None) -> budget.CostEstimate:
    wl = np.atleast_1d(np.asarray(wavelengths, float))
    mie_s = budget._mie_seconds(config, wl)
    photons = max(budget.N_FLOOR, budget.PHOTONS_AT_UNIT_ERROR / float(target) ** 2)
    budgeted = bool(max_photons) and float(max_photons) < photons
    if budgeted:
        photons = float(max_photons or 0)
    events = _events_computed(config, wl)
    return budget.CostEstimate(photons, events, mie_s, mie_s + photons * events / budget.EVENT_RATE, budgeted)


def _decisions(config, wl, events: float) -> list[str | None]:
    """check_cost at targets whose estimate is ~50 min (a warning) and ~1 year (a refusal)."""
    out: list[str | None] = []
    for seconds in (3000.0, 3e7):
        target = math.sqrt(budget.PHOTONS_AT_UNIT_ERROR * events / (budget.EVENT_RATE * seconds))
        try:
            out.append(budget.check_cost(config, wl, target))
        except budget.BudgetError as exc:
            out.append(f"refused: {exc}")
    return out


def _budget_entries(cache_dir) -> list:
    return [e for e in tablecache.entries(cache_dir) if e[2].name.startswith("coeffs-")]


@pytest.mark.parametrize("name", preset_names())
def test_a_shipped_config_s_estimate_is_the_computed_one_on_a_miss_and_on_a_hit(name, cache_dir, monkeypatch):
    config = load_config(name)
    wl = np.asarray(config.wavelengths_nm, float)
    reference = _estimate_computed(config, wl, 0.03)
    miss = budget.estimate_cost(config, wl, 0.03)
    assert len(_budget_entries(cache_dir)) == (config.particles is not None)
    with monkeypatch.context() as m:
        m.setattr(mie, "cross_sections", lambda *a, **k: pytest.fail("Mie computed on a hit"))
        hit = budget.estimate_cost(config, wl, 0.03)
        hit_lines = _decisions(config, wl, reference.events_per_photon)
    monkeypatch.setenv(tablecache.ENV_DISABLE, "1")
    off = budget.estimate_cost(config, wl, 0.03)
    off_lines = _decisions(config, wl, reference.events_per_photon)
    assert miss == reference and hit == reference and off == reference   # dataclass equality: every float bit
    assert hit_lines == off_lines
    assert hit_lines[0].startswith("estimated cost") and hit_lines[1].startswith("refused: ")


def test_a_refused_config_gives_the_same_line_on_a_miss_and_on_a_hit(cache_dir, monkeypatch):
    config = load_config("red-cotton")
    wl = np.asarray(config.wavelengths_nm, float)
    reference = _estimate_computed(config, wl, 1e-9)
    assert reference.seconds > budget.MAX_SECONDS and reference.mie_seconds < budget.MAX_SECONDS
    lines = []
    for step in ("miss", "hit"):
        if step == "hit":
            monkeypatch.setattr(mie, "cross_sections", lambda *a, **k: pytest.fail("Mie computed on a hit"))
        assert budget.estimate_cost(config, wl, 1e-9) == reference
        with pytest.raises(budget.BudgetError) as exc:
            budget.check_cost(config, wl, 1e-9)
        lines.append(str(exc.value))
    assert lines[0] == lines[1] and f"{reference.events_per_photon:.3g} events each" in lines[0]
    assert len(_budget_entries(cache_dir)) == 1


def test_the_key_follows_the_medium_and_the_wavelengths(cache_dir):
    config = load_config("red-cotton")
    wl = np.asarray(config.wavelengths_nm, float)
    budget.estimate_cost(config, wl, 0.03)
    budget.estimate_cost(config, wl[:-1], 0.03)                        # other wavelengths
    felt = load_config("red-felt")                                     # another dye and particles
    budget.estimate_cost(felt, np.asarray(felt.wavelengths_nm, float), 0.03)
    assert len(_budget_entries(cache_dir)) == 3
    budget.estimate_cost(config, wl, 0.03)                             # the first again: a hit
    assert len(_budget_entries(cache_dir)) == 3


def test_a_corrupt_entry_is_computed_again(cache_dir):
    config = load_config("red-cotton")
    wl = np.asarray(config.wavelengths_nm, float)
    first = budget.estimate_cost(config, wl, 0.03)
    (_, _, path), = _budget_entries(cache_dir)
    good = path.read_bytes()
    path.write_bytes(good[: len(good) // 2])
    assert budget.estimate_cost(config, wl, 0.03) == first == _estimate_computed(config, wl, 0.03)
    assert path.read_bytes() == good


def test_the_felt_s_exit_bin_choice_reads_the_cost_check_s_coefficients(cache_dir, monkeypatch):
    from simulate.raytrace.estimate import fiber_scatterings

    config = load_config("green-felt-mc")
    wl = np.asarray(config.wavelengths_nm, float)
    fiber = config.fiber(wl)
    mid = float(wl[wl.size // 2])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        direct = 2.0 * fiber.radius_um * fiber.medium.optical_properties(mid, with_phase=False).mu_s
    budget.estimate_cost(config, wl, 0.03)
    monkeypatch.setattr(mie, "cross_sections", lambda *a, **k: pytest.fail("Mie computed on a hit"))
    assert fiber_scatterings(fiber, wl) == direct
    assert len(_budget_entries(cache_dir)) == 1
