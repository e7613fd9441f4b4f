"""Materials of the woven-fabric tracer: a Lambertian validation limit and the fiber model's two yarns."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from simulate.woven.yarn import YarnTable

__all__ = ["K_LAMBERT", "K_FIBER", "K_FIBER_BRDF", "Lambert", "FiberSurface", "FiberBRDFAtHit", "material_kind"]

#: Material codes of the compiled shading (:mod:`simulate.woven.shading`).
K_LAMBERT = 0
K_FIBER = 1
K_FIBER_BRDF = 2


@dataclass(frozen=True)
class Lambert:
    """A Lambertian reflector of albedo ``rho`` (scalar or per wavelength): the validation limit."""

    rho: Any


@dataclass(frozen=True)
class FiberSurface:
    """The yarn material of the fiber model: Cook-Torrance surface + BSSRDF volume.

    ``roughness = 0`` is the smooth limit: specular Fresnel reflection (the limit of
    Cook-Torrance as the RMS slope goes to 0), with which a non-absorbing yarn conserves
    energy exactly (``F + (1 - F) = 1``).
    """

    table: YarnTable
    roughness: float
    n_host: float


@dataclass(frozen=True)
class FiberBRDFAtHit:
    """The original approximation: the fiber BRDF of section 5 applied at the hit point.

    Surface term as :class:`FiberSurface`; the volume term is the fiber BRDF of the cell at the
    hit point (the table's rows summed over the lit entry cells), so light always leaves where
    it arrived -- it cannot cross a yarn. Because the cell's BRDF counts light that entered
    elsewhere on the fiber, its local albedo ``a_s + A`` exceeds 1 towards grazing local
    incidence (``A ~ 1 / cos_i``); left alone, light re-reflected between yarns then gains energy
    without bound. Where it exceeds 1 the volume term is scaled down to ``1 - a_s``; the run
    reports the fraction of hits so clamped and the mean unclamped albedo
    (``info["local_albedo"]``).
    """

    table: YarnTable
    roughness: float
    n_host: float


def material_kind(material: Any) -> int:
    """The compiled shading's code of ``material``."""
    if isinstance(material, Lambert):
        return K_LAMBERT
    return K_FIBER_BRDF if isinstance(material, FiberBRDFAtHit) else K_FIBER
