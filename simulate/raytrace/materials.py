"""Materials of the fibre-assembly tracer: a Lambertian validation limit and the fiber model's two yarns."""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from simulate.fiber import tablecache
from simulate.optics import microfacet
from simulate.raytrace.yarn import YarnTable

__all__ = ["K_LAMBERT", "K_FIBER", "K_FIBER_BRDF", "ALBEDO_NODES", "Lambert", "FiberSurface", "FiberBRDFAtHit",
           "material_kind", "surface_albedo"]

#: Nodes of the surface albedo table, uniform in ``cos theta`` on [0, 1] (the shading interpolates it).
ALBEDO_NODES = 65

#: Material codes of the compiled shading (:mod:`simulate.raytrace.shading`).
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

    ``surface`` says what the surface term is reflected from (docs/physics.md 6, "Yarn surface"):

    * ``"tube"``: the tube itself, Cook-Torrance about its (shading) normal -- a single fiber
      traced as a tube (the felt's fibers, the straight-yarn test against the fiber BRDF);
    * ``"fibers"``: the fibers that make the yarn. The tube's surface is the top layer of
      parallel fibers along the local (twisted) fiber direction, at spacing ``2 R spacing_ratio``
      (1: touching, the summation's default, :mod:`simulate.fabric.fiberlayer`). A ray meets one of
      them at a point of its cross-section (shadowing by the neighbours exact, two-dimensional); the
      surface term is Cook-Torrance about THAT point's normal, seen past the neighbours (masking),
      and the entry transmission is that point's ``1 - F``. Light the surface sends towards a
      neighbour, and light falling through a gap between fibers, enters the yarn's volume (the
      fibers it meets there are the yarn's interior). The woven Monte Carlo's yarns use it
      (:func:`simulate.raytrace.fabric_beta`).
    """

    table: YarnTable
    roughness: float
    n_host: float
    surface: str = "tube"
    spacing_ratio: float = 1.0
    #: move each sampled exit along the fiber axis by the difference between the ray's axial incidence and
    #: its table row's node (docs/physics.md 6, "Axial shift"; simulate.raytrace.shading._bin_direction)
    axial_shift: bool = False

    def __post_init__(self) -> None:
        if self.surface not in ("tube", "fibers"):
            raise ValueError(f"FiberSurface: surface must be 'tube' or 'fibers', not {self.surface!r}")
        if not (self.spacing_ratio >= 1.0 and np.isfinite(self.spacing_ratio)):
            raise ValueError(f"FiberSurface: spacing_ratio must be >= 1 (1: touching fibers), not {self.spacing_ratio!r}")

    @property
    def layer_d(self) -> float:
        """The compiled shading's fiber spacing over radius (0: the tube's own surface)."""
        return 2.0 * float(self.spacing_ratio) if self.surface == "fibers" else 0.0


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


@functools.lru_cache(maxsize=16)
def _albedo(roughness: float, n_host: float) -> np.ndarray:
    inputs = {"roughness": roughness, "n_host": n_host, "nodes": ALBEDO_NODES}
    key = tablecache.content_key("albedo", inputs, ("simulate.optics.microfacet", "simulate.optics.fresnel",
                                                    "simulate.raytrace.materials"))

    def compute() -> dict[str, np.ndarray]:
        cos = np.linspace(0.0, 1.0, ALBEDO_NODES)
        with warnings.catch_warnings():   # the grazing end of the table is known to be rough
            warnings.simplefilter("ignore")
            return {"albedo": np.asarray(microfacet.directional_albedo(np.arccos(cos), roughness, n_host), np.float64)}

    return tablecache.cached(key, compute)[0]["albedo"]


def surface_albedo(roughness: float, n_host: float) -> np.ndarray:
    """The Cook-Torrance surface's directional albedo at :data:`ALBEDO_NODES` ``cos theta`` nodes (a fresh copy).

    Computed once per process and (roughness, index), and kept in the table cache
    (:mod:`simulate.fiber.tablecache`): every trace of a run shares it. ``roughness = 0`` (the smooth
    limit, no table): two zeros.
    """
    if roughness <= 0.0:
        return np.zeros(2)
    return _albedo(float(roughness), float(n_host)).copy()
