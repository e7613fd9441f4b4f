"""The one relative error and the guards on a target (simulate.montecarlo.accuracy)."""

from __future__ import annotations

import numpy as np
import pytest

from simulate.montecarlo import ParameterError
from simulate.montecarlo.accuracy import check_target, relative_error


def test_relative_error_is_relative_to_each_directions_spectral_peak():
    # direction 0: peak 2, u 0.1 at both wavelengths -> 0.05 each; direction 1: peak 10, u 0.5 -> 0.05
    value = np.array([[2.0, 0.2], [10.0, 1.0]])
    u = np.array([[0.1, 0.1], [0.5, 0.5]])
    assert relative_error(value, u) == pytest.approx(0.05, rel=1e-12)
    # pointwise it would be 0.5 at the dark wavelengths: the definition is the peak's
    assert relative_error(value, u) < np.sqrt(np.mean((u / value) ** 2))


def test_relative_error_ignores_directions_below_a_thousandth_of_the_brightest():
    value = np.array([[1.0, 1.0], [1e-4, 1e-4]])
    u = np.array([[0.01, 0.01], [1.0, 1.0]])  # the dim direction's huge u is left out
    assert relative_error(value, u) == pytest.approx(0.01, rel=1e-12)
    assert relative_error(np.zeros((2, 3)), np.ones((2, 3))) == 0.0


@pytest.mark.parametrize("bad", [0, 0.0, -0.1, 1.0, 2, float("nan"), float("inf"), True, "0.1", None])
def test_a_target_outside_0_1_is_refused(bad):
    with pytest.raises(ParameterError, match="target_rel_err"):
        check_target(bad)


def test_zero_targets_never_reach_a_division():
    from simulate.fiber import Fiber, volume_brdf
    from simulate.media.medium import HGMedium
    from simulate.raytrace import table_photons

    fiber = Fiber(radius_um=5.0, n_host=1.5, medium=HGMedium(mu_s=0.1, mu_a=0.0, g=0.0), roughness=0.3)
    w = np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(ParameterError, match="target_rel_err"):
        volume_brdf(fiber, w, w, [500.0], target_rel_err=0.0)
    with pytest.raises(ParameterError, match="target_rel_err"):
        table_photons(0.0)
