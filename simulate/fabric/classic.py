"""The classic fabric model: a flat Cook-Torrance surface over a Lambertian volume (docs/physics.md section 7).

``beta = rho_d(lambda) + pi f_CT(w_i, w_o)``: the volume albedo ``rho_d`` of the fiber under
normal incidence (:func:`simulate.fiber.normal_albedo`) as a Lambertian term, and the surface's
Cook-Torrance term with the host index and the fabric's RMS slope.
"""

from __future__ import annotations

import numpy as np

from simulate.optics import microfacet

__all__ = ["classic_beta"]


def classic_beta(rho_d: np.ndarray, w_i: np.ndarray, w_o: np.ndarray, rms_slope: float,
                 n_host: float) -> np.ndarray:
    """``beta = rho_d(lambda) + pi f_CT(w_i, w_o)`` ``[G, L]`` (fabric frame, flat surface)."""
    rho_d = np.atleast_1d(np.asarray(rho_d, float))
    f_ct = microfacet.cook_torrance(np.atleast_2d(w_i), np.atleast_2d(w_o), rms_slope, n_host)
    return rho_d[None, :] + np.pi * f_ct[:, None]
