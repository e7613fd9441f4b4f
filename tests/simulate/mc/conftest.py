"""Shared references for the Monte Carlo kernel tests (independent of the kernel code)."""

from __future__ import annotations

import numpy as np
import pytest


def fresnel_reference(cos_i: np.ndarray, n1: float, n2: float) -> np.ndarray:
    """Unpolarised Fresnel reflectance from the textbook amplitudes (Born & Wolf 1.5.21)."""
    c = np.clip(np.abs(np.asarray(cos_i, dtype=float)), 0.0, 1.0)
    sin2_t = (n1 / n2) ** 2 * (1.0 - c * c)
    tir = sin2_t >= 1.0
    ct = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = ((n1 * c - n2 * ct) / (n1 * c + n2 * ct)) ** 2
        rp = ((n2 * c - n1 * ct) / (n2 * c + n1 * ct)) ** 2
    return np.where(tir, 1.0, 0.5 * (rs + rp))


def refract_vectors(u: np.ndarray, normal: np.ndarray, eta: float) -> tuple[np.ndarray, np.ndarray]:
    """Snell refraction of unit rows ``u`` at ``normal`` (facing the incident side); (t, tir mask)."""
    cos_i = -np.sum(u * normal, axis=1)
    sin2_t = eta * eta * (1.0 - cos_i * cos_i)
    tir = sin2_t >= 1.0
    cos_t = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    t = eta * u + (eta * cos_i - cos_t)[:, None] * normal
    return t / np.linalg.norm(t, axis=1)[:, None], tir


@pytest.fixture(scope="session")
def van_de_hulst() -> dict[str, float]:
    """MCML manual Table 6.1 case and its reference values."""
    return {"mu_a": 10.0, "mu_s": 90.0, "g": 0.75, "n": 1.0, "thickness": 0.02}


@pytest.fixture(scope="session")
def fresnel_ref():
    """The independent Fresnel reference :func:`fresnel_reference`."""
    return fresnel_reference


@pytest.fixture(scope="session")
def refract_ref():
    """The independent vector refraction :func:`refract_vectors`."""
    return refract_vectors
