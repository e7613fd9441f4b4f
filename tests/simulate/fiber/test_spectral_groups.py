"""A smooth material's spectrum across the white Monte Carlo's wavelength groups (simulate.fiber.spectral).

Each wavelength group walks once and re-weights its paths to its wavelengths, so a group's values share
its noise, and two groups' walks are independent: where one group's values end and the next's begin the
spectrum stepped by the difference of two independent errors. Neighbouring groups are now blended
across their boundary (``blended_groups``): the spectrum of a material whose scattering is smooth in
wavelength must have no step at a boundary, and the error each value reports must still be its spread
over seeds.
"""

from __future__ import annotations

import math

import numpy as np

from simulate.fiber import Fiber
from simulate.fiber import farfield as FF
from simulate.fiber.spectral import blended_groups, spectral_optics, wavelength_groups
from simulate.media.medium import HGMedium

WL = np.arange(400.0, 701.0, 10.0)
W_IN = np.array([0.3, -0.2, math.sqrt(1 - 0.13)])
W_OUT = np.array([[0.1, 0.5, math.sqrt(1 - 0.26)], [0.0, -0.7, math.sqrt(0.51)]])
W_T = (0.0, 0.5, 0.9)


class SlopedScatterers:
    """Henyey-Greenstein scatterers whose ``mu_s`` falls as ``1 / lambda``: smooth, yet wide enough in
    ``log mu_s`` (0.56 over 400-700 nm) to need several walk groups."""

    def optical_properties(self, wavelength_nm: float, with_phase: bool = True):
        return HGMedium(mu_s=0.08 * 550.0 / wavelength_nm, mu_a=0.004, g=0.6).optical_properties(wavelength_nm)


def _fiber() -> Fiber:
    return Fiber(radius_um=10.0, n_host=1.5, medium=SlopedScatterers(), roughness=0.3, cell_width_deg=20)


def _beta(seed: int, photons_per_row: int) -> tuple[np.ndarray, np.ndarray]:
    """``beta, u`` of two independent exit tables (seeds ``2 seed``, ``2 seed + 1``), as the structured
    summation forms them (:func:`simulate.fiber.farfield.controlled_halves`): mean and half difference."""
    halves = [FF.exit_table(_fiber(), WL, w_t=W_T, photons_per_row=photons_per_row, seed=2 * seed + h, threads=1,
                            cache=False).far_field(W_IN, W_OUT) for h in range(2)]
    return 0.5 * (halves[0] + halves[1]), 0.5 * np.abs(halves[0] - halves[1])


def test_the_material_needs_several_groups():
    groups = wavelength_groups(spectral_optics(_fiber(), WL), max_size=7)
    assert len(groups) >= 4
    assert np.array_equal(np.concatenate(groups), np.arange(WL.size))


def test_no_step_at_the_group_boundaries():
    # unblended groups gave steps of 10-16 % at the boundaries against median steps of ~1 %
    # (largest / median 10-14 over seeds 0-4)
    beta, u = _beta(0, 2000)
    steps = np.abs(np.diff(np.log(beta), axis=1))
    assert steps.max() < 5.0 * np.median(steps)
    # and no step is larger than the relative error the values report
    assert steps.max() < 1.5 * math.sqrt(np.mean((u / beta) ** 2))


def test_reported_error_is_the_spread_over_seeds():
    seeds = 8
    runs = [_beta(s, 600) for s in range(seeds)]
    betas = np.array([b for b, _ in runs])
    us = np.array([u for _, u in runs])
    spread = betas.std(axis=0, ddof=1)               # per value, over seeds
    # u = |b1 - b2| / 2 estimates the standard error of the mean with one degree of freedom: its mean
    # square over seeds and values is the variance; the values of a spectrum are correlated, so
    # both sides have few effective degrees of freedom and the bounds are wide
    ratio = math.sqrt(np.mean(us ** 2) / np.mean(spread ** 2))
    assert 0.6 < ratio < 1.7


def test_blend_weights_add_up_to_one_and_stay_near_the_boundary():
    groups = [np.arange(0, 5), np.arange(5, 12), np.arange(12, 13), np.arange(13, 16)]
    total = np.zeros(16)
    for k, (scored, weight) in enumerate(blended_groups(groups, 2)):
        total[scored] += weight
        assert np.all(np.diff(scored) == 1)          # consecutive wavelengths
        own = groups[k]
        assert set(scored) >= set(own)
        # a walk scores at most 2 wavelengths beyond its group on each side
        assert scored[0] >= own[0] - 2 and scored[-1] <= own[-1] + 2
        assert np.all(weight[np.isin(scored, own)] >= 0.5)   # its own wavelengths mostly its own
    assert np.allclose(total, 1.0)
    # a one-wavelength group is not blended: its neighbours' walks do not reach past it
    assert all(12 not in s for s, _ in (blended_groups(groups, 2)[1], blended_groups(groups, 2)[3]))
    assert blended_groups(groups, 0)[0][0].tolist() == groups[0].tolist()
