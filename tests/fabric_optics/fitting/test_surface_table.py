"""The structured summation's surface table (simulate.fabric.fiberlayer.surface_table), computed in compiled code:
equal to the composition of fiberlayer.surface_Q it replaces, which the fit's RMS-slope lattice computes at every
lattice point (fabric_optics.fitting.problem.SURFACE_LATTICE_STEP), to within a few units in the last place.

Why not bit for bit: numba (LLVM) and numpy each pick their ``exp``, ``sqrt``, ``pow`` and their vector widths by
the CPU they run on (SVML and AVX-512 paths on some CPUs, scalar libm on others), and each of those may differ
from the correctly rounded result by one ulp. The table chains about a dozen such operations per element, so the
two sides agree bit for bit on some CPUs and not on others. The bound below (32 ulp, relative 7e-15, plus an
absolute floor of 1e-15 of the table's maximum for elements that come out of a cancellation near zero) holds on
every CPU and is still ten orders of magnitude below any error that changes a fit: a wrong angle, a missing
factor or a swapped index moves elements by percent."""

from __future__ import annotations

import math

import numpy as np
import pytest

import simulate.fabric.fiberlayer as FL
from simulate.fiber import Fiber
from simulate.media.medium import HGMedium
from simulate.optics import microfacet


def _by_surface_q(roughness, n_host, masking, spacing_ratio, step_deg, phi_step_deg, n_psi):
    """The table as :func:`simulate.fabric.fiberlayer.surface_Q` gives it, one incidence at a time."""
    fiber = Fiber(radius_um=1.0, n_host=n_host, medium=HGMedium(mu_s=0.0, mu_a=0.0, g=0.0), roughness=roughness)
    th, ph_i, ph_o, w_out = FL.layer_grid(step_deg, phi_step_deg)
    spacing = 2.0 * spacing_ratio if masking else None
    out = np.zeros((th.size, ph_i.size, th.size, ph_o.size))
    up = w_out[:, 2] > 0
    for a, t_i in enumerate(th):
        for b, p_i in enumerate(ph_i):
            w_in = microfacet.direction(math.radians(t_i), math.radians(p_i))
            if w_in[2] < 1e-12:
                continue
            q = np.zeros(w_out.shape[0])
            q[up] = FL.surface_Q(fiber, w_in, w_out[up], spacing, spacing, n_psi)
            out[a, b] = q.reshape(th.size, ph_o.size) / (2.0 * spacing_ratio)
            if t_i == 0.0:
                out[a, 1:] = out[a, 0]
                break
    return out


@pytest.mark.parametrize("args", [
    (0.147, 1.53, True, 1.0, 15.0, 30.0, 180),    # the felt's: azimuth sum over two pairwise blocks
    (0.31, 1.49, True, 1.3, 15.0, 30.0, 90),      # one block, spaced fibers
    (0.05, 1.6, False, 1.0, 22.5, 45.0, 60),      # no masking, a narrow lobe
])
def test_the_compiled_surface_table_equals_surface_q_to_a_few_ulp(args, monkeypatch):
    want = _by_surface_q(*args)
    assert want.max() > 0.01                          # a table with light in it (else nothing is compared)
    calls = []
    real = microfacet.cook_torrance

    def counted(*a, **k):
        calls.append(np.shape(a[0]))
        return real(*a, **k)

    monkeypatch.setattr(microfacet, "cook_torrance", counted)
    FL.surface_table.cache_clear()
    got = FL.surface_table(*args)
    np.testing.assert_allclose(got, want, rtol=32 * np.finfo(float).eps, atol=1e-15 * want.max())
    assert calls == []                                # no point through numpy's cook_torrance
    assert not got.flags.writeable


def test_the_surface_table_refuses_a_slope_or_index_cook_torrance_refuses():
    FL.surface_table.cache_clear()
    with pytest.raises(ValueError, match="roughness must be a finite number > 0"):
        FL.surface_table(0.0, 1.5, True, 1.0, 30.0, 45.0, 36)
    with pytest.raises(ValueError, match="n_host must be a finite number > 0"):
        FL.surface_table(0.2, float("nan"), True, 1.0, 30.0, 45.0, 36)
