"""Simulation configs: what fiber, what fabric, how accurately (TOML, read with ``tomllib``).

A config names the fiber (radius, host index, host absorption spectrum = the dye), the scattering
medium inside it (Mie particles, or a direct Henyey-Greenstein medium for validation), the surface
roughness, the fabric (the woven micro-element of :mod:`simulate.geometry.weave`, or a
``[structure]``), a blend's fiber populations, the method settings and the seed. ``simulate fiber``,
``simulate fabric`` and the fit take a config path or the name of a shipped preset (``red-cotton``,
in :mod:`simulate.configs`).

Public objects
--------------
- :func:`load_config`, :func:`parse_config`: a path, preset name or TOML text to a validated
  :class:`SimulationConfig` (with its :class:`ParticleSpec`, :class:`DyeSpectrum` and
  :class:`Population` parts); :func:`preset_names`, :func:`resolve_config_path`.
- :func:`weave_from_config`: the :class:`~simulate.geometry.weave.Weave` of a config's ``[weave]``.
- :func:`require_single_population`: the one refusal of a blend by a one-fiber model or command.
- :class:`ConfigError`: the one error of a bad config.
- :data:`SCHEMA`: every table and field, with units, bounds and defaults.

Notes
-----
Every bad field ends in ONE :class:`ConfigError` whose message names the file and the field,
e.g. ``red.toml: fiber.radius_um must be a number > 0, got "abc"``. Unknown fields are errors
too (a misspelt key must not be silently ignored).

The schema is :data:`SCHEMA`; ``docs/scripts/gen_reference.py`` renders it, with the table of known
keys, as the config reference (docs/reference/config.md).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass, field
from importlib import resources
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np

from gonio.data import toml_text
from simulate.config_dye import DyeSpectrum, dye_from_table, knots_curve
from simulate.config_table import ConfigError, Table, show
from simulate.fabric.structure import structure_from_table
from simulate.geometry.weave import PRESETS, Weave, WeaveError, preset
from simulate.geometry.wif import weave_from_wif
from simulate.media.medium import HGMedium, LogNormalSize, MieMedium, Spectrum

__all__ = [
    "SCHEMA",
    "ConfigError",
    "DyeSpectrum",
    "ParticleSpec",
    "Population",
    "SimulationConfig",
    "knots_curve",
    "load_config",
    "parse_config",
    "preset_names",
    "require_single_population",
    "resolve_config_path",
]


#: The config schema: units, an annotated example of every table and field (bounds and defaults in the
#: comments) and the rules across tables. Rendered as docs/reference/config.md by
#: ``docs/scripts/gen_reference.py`` (an RST literal block after ``::``).
SCHEMA = """\
Lengths in micrometres, absorption/scattering coefficients in 1/um, wavelengths in nm (vacuum).
A *spectrum* is either a number (constant) or a table ``{wavelength_nm = [...], values = [...]}``
(strictly increasing wavelengths, interpolated linearly, end values held outside)::

    name = "red-cotton"                # optional, default: the file's stem
    description = "..."                # optional
    seed = 0                           # optional, default 0 (integer >= 0)

    [fiber]                            # required
    radius_um = 7.5                    # > 0
    n_host = 1.557                     # real host index, >= 1
    cell_width_deg = 10                # optional, (0, 180]: angular width of the top cell B
    route = "nee"                      # optional: the fiber route, "nee" | "beam" | "bssrdf"
    dye_profile = "uniform"            # optional: where [fiber.dye] sits across the fiber: "uniform" | "ring"
    # dye_depth_um = 2.0               #   (from the surface to dye_depth_um) | "core" (below a clear skin of
                                       #   dye_depth_um); dye_depth_um in (0, radius_um), ring and core only;
                                       #   walked by the Monte Carlo's exit tables (simulate.montecarlo.kernel)
    scatterer_profile = "uniform"      # optional: where the scatterers ([particles] or [medium] mu_s) sit:
    # scatterer_depth_um = 2.0         #   "uniform" | "skin" (from the surface to scatterer_depth_um, a clear
                                       #   core) | "core" (below a clear skin of scatterer_depth_um); depth in
                                       #   (0, radius_um), skin and core only; the clear part keeps the host's
                                       #   index and dye; particles with k = 0; every population shares it;
                                       #   walked by the exit tables and the yarn tables (summation, --method mc)

    [fiber.dye]                        # optional: host absorption mu_a_host(lambda), 1/um; ONE of
    wavelength_nm = [400, 500, 600]    #   a table: wavelength_nm + mu_a_per_um (>= 0)
    mu_a_per_um = [0.1, 0.5, 0.001]
    # curve = "gaussian-bands"         #   or a named smooth curve:
    # baseline_per_um = 0.001          #   mu_a = baseline + sum_j peak_j exp(-(l - c_j)^2 / (2 w_j^2))
    # bands = [{center_nm = 520, width_nm = 40, peak_per_um = 0.4}]
    # curve = "logistic-edge"          #   mu_a = long + (short - long) / (1 + exp((l - edge) / width))
    # short_per_um = 0.5, long_per_um = 0.001, edge_nm = 590, width_nm = 12
    # curve = "knots"                  #   any colour: log10 mu_a (1/um) at K >= 2 knot wavelengths,
    # wavelength_nm = [400, 450, ...]  #   strictly increasing; PCHIP in log10 between knots, the end
    # log10_per_um = [-1, -0.5, ...]   #   values held outside; each value in [-6, 2]

    [particles]                        # Mie spheres in the host (exclusive with [medium])
    n = 1.0                            # spectrum, > 0: real part of the particle index
    k = 0.0                            # spectrum, >= 0: absorption index (index n - i k)
    radius_um = 0.25                   # ONE of radius_um and [particles.size]
    # size = {median_radius_um = 0.25, sigma_g = 1.5}     (log-normal number distribution)
    volume_fraction = 0.05             # ONE of volume_fraction in [0, 1) and number_density_per_um3

    [medium]                           # direct HG medium for validation (exclusive with [particles])
    mu_s = 0.5                         # 1/um, >= 0
    mu_a = 0.001                       # 1/um, >= 0 (total absorption: no [fiber.dye] with [medium])
    g = 0.8                            # (-1, 1)

    [surface]
    rms_slope = 0.3                    # Beckmann RMS slope m of the fiber surface, > 0
    transmission_rms_slope = 0.0       # [0, 1]: the same surface for the light the volume walk sends
                                       #   through it (0: smooth); the Monte Carlo (yarn tables) only
                                       #   (simulate.montecarlo.rough, docs/physics.md 3)
    # transmission_rms_slope_around = 0.3  # [0, 1], optional: an anisotropic boundary, the line above
                                       #   then the slope along the fiber axis, this one about it

    [weave]                            # optional: the woven micro-element (simulate.geometry.weave)
    matrix = [[1, 0], [0, 1]]          # rows of 0/1 (1 = warp over weft), rectangular; at most ONE
    # preset = "twill"                 #   of matrix, preset ("plain" | "twill" | "satin") and
    # wif = "pattern.wif"              #   wif (a WIF 1.1 file, relative to this file); none: plain
    spacing_um = 250                   # > 0   (default 300)
    width_um = 200                     # > 0   (default 250; <= spacing_um, checked by the weave)
    height_um = 80                     # > 0   (default 100)
    crimp = 1.0                        # (0, 1] (default 1)
    points_per_span = 16               # mesh intervals per crossing interval, >= 1 (default 16)
    sides = 48                         # mesh intervals around the yarn section, >= 3 (default 48)
                                       # the mesh: 4 sides points_per_span n_warp n_weft <= 2e6
                                       #   triangles (simulate.geometry.weave.MAX_TRIANGLES)

    [method]                           # optional, defaults shown
    target_rel_err = 0.01              # target relative standard error, (0, 1)
    max_photons = 0                    # photon budget; 0 = no cap
    threads = 0                        # 0 = all available
    axial_nodes = 5                    # woven/felt Monte Carlo: the yarn table's rows in |w_t| (incidence
                                       #   along the fiber), [2, 64], steps of 1/(N-1) from 0, the last at 0.95
                                       #   (docs/physics.md 6, "Axial nodes")
    axial_shift = false                # woven/felt Monte Carlo: move a table row's exits along the fiber
                                       #   axis to the ray's own axial incidence (docs/physics.md 6)
    exit_bins = [10, 20]               # woven/felt Monte Carlo: the yarn table's exit directions, binned
                                       #   in mu (uniform in cos, [2, 20]) x phi ([4, 40]) per exit cell.
                                       #   Default: [10, 20] for a felt of nearly clear fibers (coarser
                                       #   bins smear their exit cones), [5, 10] otherwise (turbid fibers
                                       #   and woven yarns converge there at half the trace time)
                                       #   (docs/physics.md 6, "Exit directions")
    felt_realisations = 4              # felt Monte Carlo: independent realisations of the felt a run
                                       #   averages, an even number in [2, 32], half on each table
                                       #   half; its error holds their spread (2: one per half, the
                                       #   halves' difference; docs/notes/felt-structure.md 8,
                                       #   "The Monte Carlo noise")

    [structure]                        # optional: the summation over the fabric's visible fibers in all
    kind = "woven"                     #   their orientations; fields and defaults in
    warp_twist_deg = 24                #   simulate.fabric.structure.structure_from_table. Absent: the
                                       #   summation is the carpet of top cells (docs/physics.md 6)

    [[populations]]                    # optional: a blend of fiber populations (absent: one population, the
    share = 0.5                        #   fiber above); share: the population's fraction of the fibers by
    name = "yellow"                    #   number (of fiber length), (0, 1], the shares adding up to 1;
                                       #   name optional. Each may override the fiber above:
    [populations.fiber]                #   any of radius_um, n_host (the Monte Carlo needs them the same
    radius_um = 8                      #   in every population), dye_profile and dye_depth_um,
    [populations.fiber.dye]            #   a whole dye (replacing the fiber's; same forms as [fiber.dye]),
    wavelength_nm = [400, 700]
    mu_a_per_um = [0.2, 0.01]
    # [populations.particles]          #   a whole [particles] table (replacing the config's),
    # [populations.surface]            #   any of the [surface] fields (rms_slope: one for the Monte Carlo)
    # By mass: a population's mass share is its share times its radius squared (equal densities),
    # normalised; give the shares by number.

    [wavelengths]                      # optional: the wavelengths of `simulate fiber` tables
    start_nm = 390                     # (`simulate fabric` uses the plan's wavelengths)
    stop_nm = 710
    step_nm = 10
    # or: list_nm = [450, 550, 650]

A config with ``[[populations]]`` is a blend: every fiber of the fabric is one of the populations, drawn
by its share. The structured summation mixes the populations' layer tables by share (exact for the
fabric's top layer); the felt Monte Carlo mixes their exit tables by share, so that each fiber a ray meets
is, in expectation, drawn from a population by share (exact for light that meets a fiber once); the woven
Monte Carlo mixes the piles of its yarns likewise, so that each yarn a ray enters is, in expectation, the
pile of a population drawn by share (a mélange yarn; docs/physics.md 6, "Fiber populations"). Models
and commands that take one fiber refuse a blend with one line (``simulate.config.require_single_population``).
One population of share 1 without overrides is the config without ``[[populations]]``, bit for bit.

Exactly one of ``[particles]`` and ``[medium]`` is required. The removed ``[structure]`` switches are
refused with what to do (``simulate.fabric.structure.REMOVED_KEYS``).
"""


_PRESET_PACKAGE = "simulate.configs"
_DEFAULT_WAVELENGTHS = tuple(float(w) for w in np.arange(390.0, 710.0 + 1e-9, 10.0))
#: The fiber routes of ``[fiber] route``.
ROUTES = ("nee", "beam", "bssrdf")
#: ``[fiber] dye_profile``: where the dye sits across the fiber (simulate.fiber.Fiber.dye_profile)
DYE_PROFILES = ("uniform", "ring", "core")
#: ``[fiber] scatterer_profile``: where the scatterers sit across the fiber (simulate.fiber.Fiber.scatterer_profile)
SCATTERER_PROFILES = ("uniform", "skin", "core")
#: ``[method] exit_bins`` when not given: None, chosen per run by
#: :func:`simulate.raytrace.estimate.default_exit_bins` ([10, 20] for a felt of nearly clear fibers,
#: whose exit cones coarser bins smear; [5, 10] for turbid fibers and woven yarns, which converge
#: there at half the trace time; docs/physics.md 6, "Exit directions").
DEFAULT_EXIT_BINS = None
#: ``[method] axial_shift`` when not given (docs/physics.md 6, "Axial shift")
DEFAULT_AXIAL_SHIFT = False
#: ``[method] axial_nodes`` when not given (docs/physics.md 6, "Axial nodes")
DEFAULT_AXIAL_NODES = 5
#: ``[method] felt_realisations`` when not given: the felt Monte Carlo's independent realisations of the felt
#: (:func:`simulate.raytrace.estimate.combine_realisations`). Four, by measurement: against two, one run's noise
#: falls to the rays' own and the reported error holds the seeds' spread, for ~15 % more CPU; eight and sixteen
#: gain nothing more (docs/notes/felt-structure.md 8, "The Monte Carlo noise")
DEFAULT_FELT_REALISATIONS = 4
#: the most ``[method] felt_realisations``
MAX_FELT_REALISATIONS = 32


def axial_node_grid(n: int) -> tuple[float, ...]:
    """``n`` yarn-table nodes in ``|w_t|``.

    Steps of ``1 / (n - 1)`` from 0, the last node at 0.95 instead of 1 (light travelling exactly along
    the fiber axis does not enter its side).

    >>> axial_node_grid(5)
    (0.0, 0.25, 0.5, 0.75, 0.95)
    """
    n = int(n)
    return tuple(round(k / (n - 1), 6) for k in range(n - 1)) + (0.95,)

#: The keys of the schema's tables (a key outside them is refused, with a suggestion, before any
#: field is read: :class:`simulate.config_table.Table`).
_FIELDS: dict[str, tuple[str, ...]] = {
    "fiber": ("radius_um", "n_host", "cell_width_deg", "route", "dye", "dye_profile", "dye_depth_um",
              "scatterer_profile", "scatterer_depth_um"),
    "fiber.dye": ("wavelength_nm", "mu_a_per_um", "curve", "baseline_per_um", "bands", "short_per_um",
                  "long_per_um", "edge_nm", "width_nm", "log10_per_um"),
    "particles": ("n", "k", "radius_um", "size", "volume_fraction", "number_density_per_um3"),
    "weave": ("matrix", "preset", "wif", "spacing_um", "width_um", "height_um", "crimp", "points_per_span", "sides"),
    "method": ("target_rel_err", "max_photons", "threads", "exit_bins", "axial_shift", "axial_nodes",
               "felt_realisations"),
    "populations": ("name", "share", "fiber", "particles", "surface"),
    "populations.fiber": ("radius_um", "n_host", "dye", "dye_profile", "dye_depth_um"),
    "surface": ("rms_slope", "transmission_rms_slope", "transmission_rms_slope_around"),
}
#: how far the populations' shares may add up from 1
SHARE_TOLERANCE = 1e-6


def _spectrum(t: Table, key: str, default: float | None, *, gt: float | None = None,
              ge: float | None = None, required: bool = False) -> float | Spectrum | None:
    """A number or a ``{wavelength_nm, values}`` table (see the schema)."""
    value = t.raw(key, default, required)
    if value is None or not isinstance(value, dict):
        if value is not None:
            t.used.discard(key)
            return t.number(key, default, gt=gt, ge=ge, required=required)
        return None
    sub = Table(value, t.name(key), t.file)
    wl = sub.numbers("wavelength_nm", ge=0.0)
    values = sub.numbers("values")
    sub.done()
    if len(wl) != len(values):
        raise sub.fail("values", f"must have as many items as wavelength_nm ({len(wl)}), got {len(values)}")
    if any(b <= a for a, b in pairwise(wl)):
        raise sub.fail("wavelength_nm", "must be strictly increasing")
    for k, v in enumerate(values):
        if (gt is not None and not v > gt) or (ge is not None and not v >= ge):
            bound = f"> {gt:g}" if gt is not None else f">= {ge:g}"
            raise sub.fail("values", f"item {k} must be {bound}, got {show(v)}")
    return Spectrum(np.asarray(wl), np.asarray(values), name=f"{t.file}: {t.name(key)}")


# ------------------------------------------------------------------------------------------
# the config objects


@dataclass(frozen=True)
class ParticleSpec:
    """Mie particles of the ``[particles]`` table (see the schema)."""

    n: float | Spectrum
    k: float | Spectrum
    radius_um: float | None
    size: LogNormalSize | None
    volume_fraction: float | None
    number_density_per_um3: float | None


@dataclass(frozen=True)
class Population:
    """One fiber population of ``[[populations]]``: its share by number and its fiber.

    Every field is resolved: the config's own where the population does not override it.
    """

    name: str
    share: float
    radius_um: float
    n_host: float
    dye: DyeSpectrum | None
    particles: ParticleSpec | None
    rms_slope: float
    transmission_rms_slope: float
    transmission_rms_slope_around: float | None
    dye_profile: str = "uniform"
    dye_depth_um: float = 0.0
    #: the config's ``[fiber] scatterer_profile`` and ``scatterer_depth_um`` (every population's)
    scatterer_profile: str = "uniform"
    scatterer_depth_um: float = 0.0


@dataclass(frozen=True)
class SimulationConfig:
    """A validated simulation config (see the module docstring for the schema)."""

    name: str
    description: str
    source: str
    text: str
    sha256: str
    seed: int
    radius_um: float
    n_host: float
    cell_width_deg: float
    dye: DyeSpectrum | None
    particles: ParticleSpec | None
    hg: tuple[float, float, float] | None
    rms_slope: float
    weave: dict
    route: str
    target_rel_err: float
    max_photons: int | None
    threads: int | None
    wavelengths_nm: tuple[float, ...] = field(default=_DEFAULT_WAVELENGTHS)
    #: the [structure] section (:class:`simulate.fabric.structure.StructureSpec`), None when absent
    structure: Any = None
    #: the woven/felt Monte Carlo's yarn table: exit direction bins (mu, phi) per exit cell; None: by
    #: the fiber (:func:`simulate.raytrace.estimate.default_exit_bins`)
    exit_bins: tuple[int, int] | None = DEFAULT_EXIT_BINS
    #: ``[surface] transmission_rms_slope``: the boundary's roughness for light crossing it (0: smooth)
    transmission_rms_slope: float = 0.0
    #: ``[surface] transmission_rms_slope_around``: None (isotropic) or the slope about the fiber axis
    transmission_rms_slope_around: float | None = None
    #: ``[method] axial_shift``: the woven/felt tracer moves a table row's exits along the fiber axis to
    #: the ray's own axial incidence (docs/physics.md 6, "Axial shift")
    axial_shift: bool = False
    #: ``[method] axial_nodes``: the yarn table's rows in |w_t| (the component of the incidence along the
    #: fiber), steps of 1/(N-1) from 0, the last at 0.95
    axial_nodes: int = DEFAULT_AXIAL_NODES
    #: ``[method] felt_realisations``: the felt Monte Carlo's independent realisations of the felt, an even
    #: number (each table half traced on half of them)
    felt_realisations: int = DEFAULT_FELT_REALISATIONS
    #: ``[[populations]]``: the blend's fiber populations; None: one population, the config's fiber
    populations: tuple[Population, ...] | None = None
    #: ``[fiber] dye_profile``, ``dye_depth_um``: where the dye sits across the fiber
    dye_profile: str = "uniform"
    dye_depth_um: float = 0.0
    #: ``[fiber] scatterer_profile``, ``scatterer_depth_um``: where the scatterers sit across the fiber
    scatterer_profile: str = "uniform"
    scatterer_depth_um: float = 0.0

    def population_configs(self) -> list[tuple[float, SimulationConfig]]:
        """``(share, config)`` of each fiber population.

        Each config is this one with that population's fiber and no ``[[populations]]``; without
        ``[[populations]]``, ``[(1.0, self)]``.
        """
        if not self.populations:
            return [(1.0, self)]
        return [(p.share, dataclasses.replace(
            self, radius_um=p.radius_um, n_host=p.n_host, dye=p.dye, particles=p.particles, rms_slope=p.rms_slope,
            transmission_rms_slope=p.transmission_rms_slope,
            transmission_rms_slope_around=p.transmission_rms_slope_around, dye_profile=p.dye_profile,
            dye_depth_um=p.dye_depth_um, populations=None))
            for p in self.populations]

    def undyed(self) -> SimulationConfig:
        """The config with its fiber undyed.

        The reference a walk is traced in when its dye is applied by weights (:mod:`simulate.structwalk`).
        """
        return dataclasses.replace(self, dye=None)

    def w_t_nodes(self) -> tuple[float, ...]:
        """The yarn table's axial nodes of ``[method] axial_nodes``."""
        return axial_node_grid(self.axial_nodes)

    def medium(self, wavelengths_nm: Any | None = None) -> MieMedium | HGMedium:
        """The scattering medium; the dye spectrum is sampled at ``wavelengths_nm`` (exact there)."""
        if self.hg is not None:
            mu_s, mu_a, g = self.hg
            return HGMedium(mu_s=mu_s, mu_a=mu_a, g=g)
        p = self.particles
        assert p is not None
        wl = self.wavelengths_nm if wavelengths_nm is None else wavelengths_nm
        mu_a_host: float | Spectrum = 0.0 if self.dye is None else self.dye.as_spectrum(np.asarray(wl))
        return MieMedium(n_host=self.n_host, particle_n=p.n, particle_k=p.k, radius_um=p.radius_um,
                         size_distribution=p.size, number_density_per_um3=p.number_density_per_um3,
                         volume_fraction=p.volume_fraction, mu_a_host_per_um=mu_a_host)

    def fiber(self, wavelengths_nm: Any | None = None):
        """The :class:`simulate.fiber.Fiber` of this config (dye sampled at ``wavelengths_nm``)."""
        from simulate.fiber import Fiber

        return Fiber(radius_um=self.radius_um, n_host=self.n_host, medium=self.medium(wavelengths_nm),
                     roughness=self.rms_slope, cell_width_deg=self.cell_width_deg,
                     transmission_roughness=self.transmission_rms_slope,
                     transmission_roughness_around=self.transmission_rms_slope_around,
                     dye_profile=self.dye_profile, dye_depth_um=self.dye_depth_um,
                     scatterer_profile=self.scatterer_profile, scatterer_depth_um=self.scatterer_depth_um)

    def provenance(self) -> dict:
        """What produced a result: the config's name, source, SHA-256 and full text."""
        return {"name": self.name, "source": self.source, "sha256": self.sha256, "text": self.text}


# ------------------------------------------------------------------------------------------
# reading


def preset_names() -> list[str]:
    """Names of the configs shipped in :mod:`simulate.configs`."""
    folder = resources.files(_PRESET_PACKAGE)
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def resolve_config_path(path_or_name: str | Path) -> Path:
    """A config file path from a path or the name of a shipped preset (``red-cotton``)."""
    p = Path(path_or_name)
    if p.is_file():
        return p
    name = str(path_or_name)
    name = name[:-5] if name.endswith(".toml") else name
    if "/" not in name and name in preset_names():
        return Path(str(resources.files(_PRESET_PACKAGE) / f"{name}.toml"))
    if p.exists():
        raise ConfigError(f"{path_or_name}: is not a file; a config is a TOML file")
    raise ConfigError(f"{path_or_name}: no such config file and no preset of that name "
                      f"(presets: {', '.join(preset_names())})")


def load_config(path_or_name: str | Path) -> SimulationConfig:
    """Read and validate a config file or a preset name; raises :class:`ConfigError`."""
    path = resolve_config_path(path_or_name)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config ({exc.strerror})") from None
    is_preset = not Path(path_or_name).is_file()
    return parse_config(raw, path, source=f"preset {path.stem}" if is_preset else str(path))


def _particles(t: Table) -> ParticleSpec:
    n = _spectrum(t, "n", None, gt=0.0, required=True)
    k = _spectrum(t, "k", 0.0, ge=0.0)
    assert n is not None and k is not None     # n is required and k has a default
    if t.has("radius_um") == t.has("size"):
        raise t.fail("radius_um", "or particles.size: give exactly one (a radius or a log-normal "
                                  "size distribution)")
    radius = size = None
    if t.has("radius_um"):
        radius = t.number("radius_um", gt=0.0)
    else:
        st = t.sub("size", fields=("median_radius_um", "sigma_g"))
        assert st is not None
        median = st.number("median_radius_um", required=True, gt=0.0)
        sigma_g = st.number("sigma_g", required=True, ge=1.0, le=5.0)
        st.done()
        size = LogNormalSize(median_radius_um=median, sigma_g=sigma_g)
    if t.has("volume_fraction") == t.has("number_density_per_um3"):
        raise t.fail("volume_fraction", "or particles.number_density_per_um3: give exactly one")
    fv = t.number("volume_fraction", ge=0.0, lt=1.0) if t.has("volume_fraction") else None
    nd = t.number("number_density_per_um3", ge=0.0) if t.has("number_density_per_um3") else None
    t.done()
    return ParticleSpec(n=n, k=k, radius_um=radius, size=size, volume_fraction=fv,
                        number_density_per_um3=nd)


def _weave(t: Table, base_dir: Path) -> dict:
    """The ``[weave]`` table as a dict of the fields present.

    :func:`weave_from_config` fills the defaults and checks the geometry; ``wif`` is stored resolved
    against ``base_dir``.
    """
    out: dict = {}
    given = [key for key in ("matrix", "preset", "wif") if t.has(key)]
    if len(given) > 1:
        raise t.fail(given[1], f"cannot be combined with {t.name(given[0])}: give at most one of "
                               f"matrix, preset and wif")
    if t.has("preset"):
        out["preset"] = t.string("preset", choices=tuple(PRESETS))
    if t.has("wif"):
        wif = Path(t.string("wif") or "")
        wif = wif if wif.is_absolute() else base_dir / wif
        if not wif.is_file():
            raise t.fail("wif", f"file not found: {wif} (a relative path is taken from the config's folder)")
        out["wif"] = str(wif)
    if t.has("matrix"):
        m = t.raw("matrix")
        rows_ok = isinstance(m, list) and m and all(isinstance(r, list) and r for r in m)
        if not rows_ok or len({len(r) for r in m}) != 1 or not all(
                x in (0, 1) and not isinstance(x, bool) and isinstance(x, int) for r in m for x in r):
            raise t.fail("matrix", f"must be a rectangular list of rows of 0/1 integers, got {show(m)}")
        out["matrix"] = [list(r) for r in m]
    for key in ("spacing_um", "width_um", "height_um"):
        if t.has(key):
            out[key] = t.number(key, gt=0.0)
    if t.has("crimp"):
        out["crimp"] = t.number("crimp", gt=0.0, le=1.0)
    if t.has("points_per_span"):
        out["points_per_span"] = t.integer("points_per_span", 8, ge=1, le=100_000)
    if t.has("sides"):
        out["sides"] = t.integer("sides", 16, ge=3, le=100_000)
    t.done()
    return out


def _wavelengths(t: Table) -> tuple[float, ...]:
    if t.has("list_nm"):
        wl = t.numbers("list_nm", ge=0.0)
    else:
        a = t.number("start_nm", 390.0, gt=0.0)
        b = t.number("stop_nm", 710.0, gt=0.0)
        d = t.number("step_nm", 10.0, gt=0.0)
        if b < a:
            raise t.fail("stop_nm", f"must be >= start_nm ({a:g}), got {b:g}")
        if (b - a) / d > 10000:
            raise t.fail("step_nm", "gives more than 10000 wavelengths")
        wl = [round(a + k * d, 9) for k in range(int(math.floor((b - a) / d + 1e-9)) + 1)]
    t.done()
    for w in wl:
        if not 200.0 <= w <= 2500.0:
            raise t.fail("list_nm" if t.has("list_nm") else "start_nm",
                         f"wavelength {w:g} nm outside 200..2500 nm")
    if len(set(wl)) != len(wl) or any(b <= a for a, b in pairwise(wl)):
        raise t.fail("list_nm", "must be strictly increasing without duplicates")
    return tuple(wl)


def parse_config(raw: bytes | str, path: str | Path = "<config>", *, source: str | None = None) -> SimulationConfig:
    """Validate config TOML (bytes or str) and build a :class:`SimulationConfig`.

    Raises
    ------
    ConfigError
        With a message naming the file (its name only, ``red.toml``) and the field.
    """
    file = Path(path).name
    if isinstance(raw, str):
        raw = raw.encode("utf-8", errors="surrogatepass")
    data = toml_text.loads(raw, file, ConfigError, "config", 4)
    text = raw.decode("utf-8")                  # valid UTF-8: loads checked it
    top = Table(data, "", file)
    name = top.string("name", Path(path).stem) or Path(path).stem
    description = top.raw("description", "")
    if not isinstance(description, str):
        raise top.fail("description", f"must be a string, got {show(description)}")
    seed = top.integer("seed", 0, le=2**31 - 1)   # the Monte Carlo derives 64-bit stream seeds from it

    fib = top.sub("fiber", required=True, fields=_FIELDS["fiber"])
    assert fib is not None
    radius = fib.number("radius_um", required=True, gt=0.0, le=1e4)
    n_host = fib.number("n_host", required=True, ge=1.0, le=4.0)
    cell = fib.number("cell_width_deg", 10.0, gt=0.0, le=180.0)
    route = fib.string("route", "nee", choices=ROUTES)
    dye_t = fib.sub("dye", fields=_FIELDS["fiber.dye"])
    dye = dye_from_table(dye_t) if dye_t is not None else None
    profile, depth = _dye_profile(fib, radius, dye is not None)
    scat_profile, scat_depth = _scatterer_profile(fib, radius)
    fib.done()

    if top.has("particles") == top.has("medium"):
        raise top.fail("particles", "or medium: give exactly one table ([particles] for Mie spheres, "
                                    "[medium] for a direct Henyey-Greenstein medium)")
    particles = hg = None
    if top.has("particles"):
        pt = top.sub("particles", fields=_FIELDS["particles"])
        assert pt is not None
        particles = _particles(pt)
    else:
        mt = top.sub("medium", fields=("mu_s", "mu_a", "g"))
        assert mt is not None
        hg = (mt.number("mu_s", required=True, ge=0.0), mt.number("mu_a", required=True, ge=0.0),
              mt.number("g", required=True, gt=-1.0, lt=1.0))
        mt.done()
        if dye is not None:
            raise fib.fail("dye", "cannot be combined with [medium] (medium.mu_a is the total "
                                  "absorption of a Henyey-Greenstein medium)")

    surf = top.sub("surface", required=True, fields=_FIELDS["surface"])
    assert surf is not None
    rms_slope = surf.number("rms_slope", required=True, gt=0.0, le=1.0)
    transmission_rms_slope = surf.number("transmission_rms_slope", 0.0, ge=0.0, le=1.0)
    around = (surf.number("transmission_rms_slope_around", None, ge=0.0, le=1.0)
              if surf.has("transmission_rms_slope_around") else None)
    surf.done()

    weave_t = top.sub("weave", fields=_FIELDS["weave"])
    weave = _weave(weave_t, Path(path).parent) if weave_t is not None else {}

    mt = top.sub("method", fields=_FIELDS["method"]) or Table({}, "method", file)
    target = mt.number("target_rel_err", 0.01, gt=0.0, lt=1.0)
    max_photons = mt.integer("max_photons", 0, ge=0, le=10**15)
    threads = mt.integer("threads", 0, ge=0, le=1024)
    exit_bins = _exit_bins(mt)
    axial_shift = mt.raw("axial_shift", DEFAULT_AXIAL_SHIFT)
    if not isinstance(axial_shift, bool):
        raise mt.fail("axial_shift", f"must be true or false, got {axial_shift!r}")
    axial_nodes = mt.integer("axial_nodes", DEFAULT_AXIAL_NODES, ge=2, le=64)
    realisations = mt.raw("felt_realisations", DEFAULT_FELT_REALISATIONS)
    if (isinstance(realisations, bool) or not isinstance(realisations, int) or realisations % 2
            or not 2 <= realisations <= MAX_FELT_REALISATIONS):
        raise mt.fail("felt_realisations", f"must be an even integer in [2, {MAX_FELT_REALISATIONS}] (half of the "
                      f"realisations on each table half), got {realisations!r}")
    mt.done()

    wl_t = top.sub("wavelengths", fields=("start_nm", "stop_nm", "step_nm", "list_nm"))
    wavelengths = _wavelengths(wl_t) if wl_t is not None else _DEFAULT_WAVELENGTHS
    st_t = top.sub("structure")        # simulate.fabric.structure validates it, naming the field
    structure = None if st_t is None else structure_from_table(st_t)
    base = Population(name="", share=1.0, radius_um=radius, n_host=n_host, dye=dye, particles=particles,
                      rms_slope=rms_slope, transmission_rms_slope=transmission_rms_slope,
                      transmission_rms_slope_around=around, dye_profile=profile, dye_depth_um=depth,
                      scatterer_profile=scat_profile, scatterer_depth_um=scat_depth)
    populations = _populations(top, base, hg is not None)
    top.done()

    return SimulationConfig(
        name=name, description=description, source=source or str(path), text=text,
        sha256=hashlib.sha256(raw).hexdigest(), seed=seed, radius_um=radius, n_host=n_host,
        cell_width_deg=cell, dye=dye, particles=particles, hg=hg, rms_slope=rms_slope, weave=weave,
        route=route, target_rel_err=target, max_photons=max_photons or None,
        threads=threads or None, wavelengths_nm=wavelengths, structure=structure, exit_bins=exit_bins,
        transmission_rms_slope=transmission_rms_slope, axial_shift=axial_shift,
        transmission_rms_slope_around=around, axial_nodes=axial_nodes, felt_realisations=int(realisations),
        populations=populations,
        dye_profile=profile, dye_depth_um=depth, scatterer_profile=scat_profile, scatterer_depth_um=scat_depth)


def _populations(top: Table, base: Population, hg_medium: bool) -> tuple[Population, ...] | None:
    """``[[populations]]``: each population's share and its overrides of ``base`` (the config's fiber)."""
    if not top.has("populations"):
        top.raw("populations")
        return None
    items = top.raw("populations")
    if not isinstance(items, list) or not items or not all(isinstance(x, dict) for x in items):
        raise top.fail("populations", f"must be an array of tables ([[populations]], one per population), "
                                      f"got {show(items)}")
    out = [_population(Table(item, f"populations[{k}]", top.file, _FIELDS["populations"]), k, base, hg_medium)
           for k, item in enumerate(items)]
    total = sum(p.share for p in out)
    if abs(total - 1.0) > SHARE_TOLERANCE:
        raise top.fail("populations", f"shares must add up to 1, got {total:.6g} "
                                      f"({' + '.join(f'{p.share:g}' for p in out)})")
    names = [p.name for p in out]
    for k, n in enumerate(names):
        if n in names[:k]:
            raise top.fail(f"populations[{k}].name", f"repeats {show(n)}: give each population its own name")
    return tuple(out)


def _population(t: Table, k: int, base: Population, hg_medium: bool) -> Population:
    """Population ``k`` of ``[[populations]]`` (its table ``t``): ``base`` with the table's overrides."""
    name = t.string("name", f"population {k + 1}") or f"population {k + 1}"
    share = t.number("share", required=True, gt=0.0, le=1.0)
    assert share is not None
    fields: dict[str, Any] = {}
    ft = t.sub("fiber", fields=_FIELDS["populations.fiber"])
    if ft is not None:
        fields.update(_population_fiber(ft, base, hg_medium))
    pt = t.sub("particles", fields=_FIELDS["particles"])
    if pt is not None:
        if hg_medium:
            raise t.fail("particles", "cannot be combined with [medium]: a population overrides [particles]")
        fields["particles"] = _particles(pt)
    st = t.sub("surface", fields=_FIELDS["surface"])
    if st is not None:
        for key in ("rms_slope", "transmission_rms_slope", "transmission_rms_slope_around"):
            if st.has(key):
                fields[key] = (st.number(key, gt=0.0, le=1.0) if key == "rms_slope"
                               else st.number(key, ge=0.0, le=1.0))
        st.done()
    t.done()
    return dataclasses.replace(base, name=name, share=share, **fields)


def _population_fiber(ft: Table, base: Population, hg_medium: bool) -> dict[str, Any]:
    """A population's ``[populations.fiber]`` overrides of ``base``'s fiber (radius, index, dye, profile)."""
    fields: dict[str, Any] = {}
    if ft.has("radius_um"):
        fields["radius_um"] = ft.number("radius_um", gt=0.0, le=1e4)
    if ft.has("n_host"):
        fields["n_host"] = ft.number("n_host", ge=1.0, le=4.0)
    dt = ft.sub("dye", fields=_FIELDS["fiber.dye"])
    if dt is not None:
        if hg_medium:
            raise ft.fail("dye", "cannot be combined with [medium] (medium.mu_a is the total absorption)")
        fields["dye"] = dye_from_table(dt)
    if ft.has("dye_profile") or ft.has("dye_depth_um"):
        radius_p = fields.get("radius_um", base.radius_um)
        fields["dye_profile"], fields["dye_depth_um"] = _dye_profile(
            ft, radius_p, fields.get("dye", base.dye) is not None)
    elif "radius_um" in fields and base.dye_profile != "uniform" and not base.dye_depth_um < fields["radius_um"]:
        raise ft.fail("radius_um", f"must exceed fiber.dye_depth_um ({base.dye_depth_um:g}) of the "
                                   f"{base.dye_profile} dye it keeps, got {fields['radius_um']:g}")
    if ("radius_um" in fields and base.scatterer_profile != "uniform"
            and not base.scatterer_depth_um < fields["radius_um"]):
        raise ft.fail("radius_um", f"must exceed fiber.scatterer_depth_um ({base.scatterer_depth_um:g}) of the "
                                   f"scatterers' {base.scatterer_profile}, got {fields['radius_um']:g}")
    ft.done()
    return fields


def _dye_profile(t: Table, radius_um: float, has_dye: bool) -> tuple[str, float]:
    """``dye_profile`` and ``dye_depth_um`` of a ``[fiber]`` (or a population's) table."""
    profile = t.string("dye_profile", "uniform", choices=DYE_PROFILES) or "uniform"
    if profile == "uniform":
        if t.has("dye_depth_um"):
            raise t.fail("dye_depth_um", f"is for a ring or core dye: give {t.name('dye_profile')} = \"ring\" or "
                                         f"\"core\", or delete it")
        return profile, 0.0
    if not has_dye:
        raise t.fail("dye_profile", "places the fiber's dye: give a [fiber.dye] (or the population's) to place")
    depth = t.number("dye_depth_um", required=True, gt=0.0, lt=radius_um)
    assert depth is not None
    return profile, depth


def _scatterer_profile(t: Table, radius_um: float) -> tuple[str, float]:
    """``scatterer_profile`` and ``scatterer_depth_um`` of the ``[fiber]`` table."""
    profile = t.string("scatterer_profile", "uniform", choices=SCATTERER_PROFILES) or "uniform"
    if profile == "uniform":
        if t.has("scatterer_depth_um"):
            raise t.fail("scatterer_depth_um", f"is for scatterers in a skin or a core: give "
                                               f"{t.name('scatterer_profile')} = \"skin\" or \"core\", or delete it")
        return profile, 0.0
    depth = t.number("scatterer_depth_um", required=True, gt=0.0, lt=radius_um)
    assert depth is not None
    return profile, depth


def require_single_population(config: SimulationConfig, what: str) -> None:
    """Refuse a blend (``[[populations]]`` with more than one population) for a one-fiber ``what``.

    ``what`` is a model or command that takes one fiber; the refusal is one line naming the config and
    what to do.

    Raises
    ------
    ConfigError
        ``felt.toml: populations: simulate fit takes one fiber population, this config has 2; ...``
    """
    pops = config.populations or ()
    if len(pops) > 1:
        source = config.source
        file = f"{source[len('preset '):]}.toml" if source.startswith("preset ") else Path(source).name
        raise ConfigError(f"{file}: populations: {what} takes one fiber population, this config has {len(pops)} "
                          f"({', '.join(p.name for p in pops)}); give one population or none")


def _exit_bins(mt: Table) -> tuple[int, int] | None:
    """``[method] exit_bins``: two integers, mu bins in [2, 20] and phi bins in [4, 40]; None when not given."""
    value = mt.raw("exit_bins", None)
    if value is None:
        return None
    ok = (isinstance(value, list) and len(value) == 2
          and all(isinstance(v, int) and not isinstance(v, bool) for v in value))
    if not ok or not (2 <= value[0] <= 20 and 4 <= value[1] <= 40):
        raise mt.fail("exit_bins", f"must be [mu bins, phi bins] with mu bins in 2..20 and phi bins in 4..40, got {value!r}")
    return int(value[0]), int(value[1])


# ------------------------------------------------------------------------------------------
# the [weave] table as a geometry (the config adapter of simulate.geometry.weave)


def weave_from_config(config: SimulationConfig | str | Path) -> Weave:
    """The :class:`simulate.geometry.weave.Weave` of a simulation config's ``[weave]`` table (or of a config path/preset).

    One of ``preset``, ``wif`` (resolved against the config's directory when the config is read)
    and ``matrix``; none: the plain weave. Missing dimensions take the defaults
    :data:`simulate.geometry.weave.DEFAULT_SPACING_UM` (300), :data:`simulate.geometry.weave.DEFAULT_WIDTH_UM` (250), :data:`simulate.geometry.weave.DEFAULT_HEIGHT_UM`
    (100), :data:`simulate.geometry.weave.DEFAULT_CRIMP` (1), :data:`simulate.geometry.weave.DEFAULT_POINTS_PER_SPAN` (16), :data:`simulate.geometry.weave.DEFAULT_SIDES` (48).

    Raises
    ------
    ConfigError
        ``red.toml: weave: <what is wrong>``, naming the config file.

    Examples
    --------
    >>> w = weave_from_config("red-cotton")
    >>> w.matrix.tolist(), w.spacing_um, w.width_um, w.height_um
    ([[1, 0], [0, 1]], 300.0, 250.0, 100.0)
    """
    cfg = config if isinstance(config, SimulationConfig) else load_config(config)
    source = cfg.source
    file = f"{source[len('preset '):]}.toml" if source.startswith("preset ") else Path(source).name
    w = cfg.weave
    params = {key: w[key] for key in ("spacing_um", "width_um", "height_um", "crimp", "points_per_span", "sides")
              if key in w}
    try:
        if "preset" in w:
            return preset(w["preset"], **params)
        if "wif" in w:
            return weave_from_wif(w["wif"], **params)
        return Weave(w.get("matrix", PRESETS["plain"]), **params)
    except WeaveError as exc:
        raise ConfigError(f"{file}: weave: {exc}") from None
