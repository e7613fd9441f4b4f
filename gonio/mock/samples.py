"""Virtual samples of the mock goniophotometer: the "truth" an acquisition should recover.

Every sample exposes ``beta(theta_i, phi_i, theta_o, phi_o, wavelength_nm)``, the radiance
coefficient (radiance factor, ``beta = pi f_r``) in the fabric frame of docs/physics.md section 1
(angles in degrees, z = fabric normal, x = warp, directions pointing away from the surface),
vectorised over broadcastable numpy arrays.

Samples
-------
``lambert:RHO``
    ``beta = RHO`` everywhere (an ideal diffuse reflector of reflectance RHO).
``red-cotton``
    An analytic fabric-like sample (not derived from ``simulate``): an Oren-Nayar diffuse lobe in
    a red dye with a retro-reflection peak, a Ward gloss lobe, a forward sheen and a backscatter
    term (:class:`RedCottonSample`, whose docstring has the equations and their constants).
``FILE``
    A radiance-coefficient dataset directory (``gonio.data.read_dataset``; an imported one
    too), interpolated with ``Dataset.interpolate``; a request outside the data raises
    ``gonio.data.DatasetError``. Or an RGL ``.bsdf`` file (``gonio.data.formats.rgl_bsdf``),
    evaluated at exactly the geometry asked for: the full measured BRDF of a real material.
    The mock's photometer is spectral; an RGB sample answers at wavelength ``lambda`` with the
    spectrum whose colour is the file's RGB at that geometry: the spectral primary
    decomposition of Mallett & Yuksel (2019), linear in the RGB (:mod:`gonio.mock.upsample`,
    which says why; a three-band view's steps would not have the file's colour). A spectral ``.bsdf`` or dataset is interpolated linearly in wavelength.

The white standard of the mock is Lambertian with a flat calibrated radiance factor
:data:`WHITE_REFERENCE_BETA` (:func:`reference_beta`).

References
----------
M. Oren, S. K. Nayar, "Generalization of Lambert's reflectance model", SIGGRAPH 1994.
G. J. Ward, "Measuring and modeling anisotropic reflection", SIGGRAPH 1992.
C. Schlick, "An inexpensive BRDF model for physically-based rendering", 1994.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Protocol

import numpy as np

from .upsample import rgb_spectrum

__all__ = [
    "Sample", "LambertSample", "RedCottonSample", "DatasetSample", "WhiteReference",
    "WHITE_REFERENCE_BETA", "reference_beta", "make_sample", "SampleError", "directions",
    "KNOWN_FILES",
]

log = logging.getLogger(__name__)

WHITE_REFERENCE_BETA = 0.99
"""Calibrated radiance factor of the mock white standard (flat, Lambertian)."""


class SampleError(ValueError):
    """An unknown or unreadable sample specification (a user error)."""


class Sample(Protocol):
    """What the mock needs from a virtual sample."""

    name: str

    def beta(self, theta_i, phi_i, theta_o, phi_o, wavelength_nm) -> np.ndarray:
        """Radiance coefficient at the given fabric-frame geometry (degrees) and wavelength."""

    def describe(self) -> dict:
        """A JSON-able description for provenance."""


def directions(theta_deg, phi_deg) -> np.ndarray:
    """Unit vectors ``(sin t cos p, sin t sin p, cos t)`` stacked on the last axis."""
    t = np.radians(np.asarray(theta_deg, dtype=float))
    p = np.radians(np.asarray(phi_deg, dtype=float))
    t, p = np.broadcast_arrays(t, p)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def _broadcast(*args) -> list[np.ndarray]:
    return list(np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in args)))


class LambertSample:
    """An ideal diffuse reflector: ``beta = rho`` at every geometry and wavelength."""

    def __init__(self, rho: float):
        rho = float(rho)
        if not 0.0 <= rho <= 1.0:
            raise SampleError(f"lambert:{rho:g}: the reflectance must be in 0..1")
        self.rho = rho
        self.name = f"lambert:{rho:g}"

    def beta(self, theta_i, phi_i, theta_o, phi_o, wavelength_nm) -> np.ndarray:
        """``beta = rho`` at every geometry and wavelength."""
        ti = _broadcast(theta_i, phi_i, theta_o, phi_o, wavelength_nm)[0]
        return np.full(ti.shape, self.rho)

    def describe(self) -> dict:
        """The sample as the dataset's meta records it."""
        return {"name": self.name, "model": "lambert", "rho": self.rho}


class WhiteReference(LambertSample):
    """The mock white standard (Lambertian, :data:`WHITE_REFERENCE_BETA`)."""

    def __init__(self, beta_ref: float = WHITE_REFERENCE_BETA):
        super().__init__(beta_ref)
        self.name = f"white-reference:{beta_ref:g}"


def reference_beta(wavelength_nm) -> np.ndarray:
    """Calibrated radiance factor of the mock white standard at ``wavelength_nm``."""
    return np.full(np.shape(np.asarray(wavelength_nm, dtype=float)), WHITE_REFERENCE_BETA)


class RedCottonSample:
    """The built-in analytic red-cotton sample (not derived from ``simulate``).

    The sample's radiance coefficient::

        beta = beta_d + beta_s
        beta_d = rho_d(lambda) * [A + B max(0, cos(phi_i - phi_o)) sin(a) tan(b)]
                 * (1 + R exp(-g^2 / (2 w_r^2)))
        beta_s = c_g F(theta_d) / (4 a_x a_y sqrt(cos theta_i cos theta_o))
                 * exp(-tan^2 theta_h (cos^2 phi_h / a_x^2 + sin^2 phi_h / a_y^2))

    ``beta_d`` is the qualitative Oren-Nayar diffuse lobe (roughness sigma = 20 deg:
    ``A = 1 - 0.5 s^2/(s^2 + 0.33)``, ``B = 0.45 s^2/(s^2 + 0.09)``, ``a = max(theta_i,
    theta_o)``, ``b = min(theta_i, theta_o)``) with a mild retro-reflection (hiding) peak of
    relative height ``R = 0.12`` and width ``w_r = 8 deg`` in the angle ``g`` between ``w_i`` and
    ``w_o``. ``rho_d(lambda)`` is the red dye (:meth:`RedCottonSample.rho_d`)::

        rho_d = r_0 + r_b exp(-(lambda - 420 nm)^2 / (2 (40 nm)^2))
                + (r_red - r_0) / (1 + exp(-(lambda - 594.7 nm) / 7.1 nm))

    ``r_0 = 0.01`` (the dye absorbs nearly all green), a violet-blue shoulder ``r_b = 0.088`` (the
    bluish cast of a real red dye, which makes the hue slightly magenta, H > 0.98 rather than
    0.00) and a red plateau ``r_red = 0.92`` (undyed cotton's reflectance, the dye being
    transparent above ~620 nm), the absorption edge a logistic of 10-90 % width 31 nm. The three
    free numbers ``r_b``, the edge position and its width were fitted once so that the colour
    at the report's colour geometry (normal incidence, ``theta_o = 10 deg``, gloss included)
    matches the published measurement of red cotton (docs/physics.md section 8, linear sRGB, D65,
    CIE 1931 2 deg): H 0.988, S 0.989, V 0.80, BLUE/RED 0.080, GREEN/RED 0.011 (pinned by
    ``tests/gonio/mock/test_physics.py``). ``beta_s`` is the Ward anisotropic specular lobe
    (``pi`` times the Ward BRDF) of the fibre surfaces, spectrally neutral, wider across the
    warp (``a_x = 0.22`` along the warp x, ``a_y = 0.38`` along the weft y), with the Schlick
    Fresnel factor ``F = F0 + (1 - F0)(1 - cos theta_d)^5``, ``F0 = 0.045``, ``theta_d`` the
    angle between ``w_i`` and the half vector ``h``, weighted by the gloss fraction
    ``c_g = 0.08``: the share of the fibres' surface reflection that stays a coherent lobe at
    the scale of the fabric. The rest is spread over the hemisphere by fibre twist, crimp and
    hairiness; it is part of ``rho_d``. (A full-strength lobe would add ~0.12 of white to
    every near-normal spectrum and wash the red out to S 0.70, against the published S 0.99:
    the measurement itself bounds the near-normal gloss to about 0.01.) Both terms are
    non-negative and reciprocal.

    Angular character of a real fabric (the real felt rises 7x towards the forward
    grazing direction at 60 deg incidence and has a backscatter lobe): two more reciprocal,
    non-negative terms, and the diffuse lobe giving up energy to them at grazing angles, all
    three nothing at normal incidence or observation (``u = sin theta_i sin theta_o = 0``), so
    the published colour near the normal is unchanged::

        beta_d -> beta_d (1 - k u^2)
        beta_f = c_f (0.3 + 0.7 rho_d) u^4 ((1 - cos(phi_i - phi_o)) / 2)^2
        beta_b = c_b rho_d u^2 ((1 + cos(phi_i - phi_o)) / 2)^4

    ``beta_f`` is the forward sheen (light scattered forward along and through the fibres at
    grazing angles: part surface, part dyed, hence paler than the diffuse red), ``c_f = 1.5``;
    ``beta_b`` the backscatter towards the source's side (dyed: returned by the fibre pile),
    ``c_b = 0.5``; ``k = 0.4``, which keeps the directional albedo below 1 at every incidence and
    wavelength (``tests/gonio/mock/test_physics.py``). The constants are chosen by hand for the
    shape of a fabric's in-plane curve; cotton's forward rise is weaker than the felt's.
    """

    name = "red-cotton"
    sigma_deg = 20.0
    retro_height = 0.12
    retro_width_deg = 8.0
    alpha_x = 0.22
    alpha_y = 0.38
    f0 = 0.045
    gloss_fraction = 0.08
    sheen = 1.5
    backscatter = 0.5
    grazing_loss = 0.4
    dye_floor = 0.01
    dye_blue = 0.088
    dye_red = 0.92
    dye_edge_nm = 594.7
    dye_edge_width_nm = 7.1

    @classmethod
    def rho_d(cls, wavelength_nm) -> np.ndarray:
        """Diffuse reflectance of the dyed fibres (the module docstring's ``rho_d``)."""
        wl = np.asarray(wavelength_nm, dtype=float)
        return (cls.dye_floor + cls.dye_blue * np.exp(-0.5 * ((wl - 420.0) / 40.0) ** 2)
                + (cls.dye_red - cls.dye_floor)
                / (1.0 + np.exp(-(wl - cls.dye_edge_nm) / cls.dye_edge_width_nm)))

    def beta(self, theta_i, phi_i, theta_o, phi_o, wavelength_nm) -> np.ndarray:
        """The sample's radiance coefficient (class docstring) at the given angles (degrees) and wavelengths."""
        ti, pi_, to, po, wl = _broadcast(theta_i, phi_i, theta_o, phi_o, wavelength_nm)
        wi = directions(ti, pi_)
        wo = directions(to, po)
        ti_r, to_r = np.radians(ti), np.radians(to)
        # diffuse: qualitative Oren-Nayar + retro-reflection peak
        s2 = np.radians(self.sigma_deg) ** 2
        a_coef = 1.0 - 0.5 * s2 / (s2 + 0.33)
        b_coef = 0.45 * s2 / (s2 + 0.09)
        alpha = np.maximum(ti_r, to_r)
        beta_ang = np.minimum(ti_r, to_r)
        cos_dphi = np.cos(np.radians(pi_ - po))
        on = a_coef + b_coef * np.maximum(0.0, cos_dphi) * np.sin(alpha) * np.tan(beta_ang)
        g = np.degrees(np.arccos(np.clip(np.sum(wi * wo, axis=-1), -1.0, 1.0)))
        retro = 1.0 + self.retro_height * np.exp(-0.5 * (g / self.retro_width_deg) ** 2)
        beta_d = self.rho_d(wl) * on * retro
        # specular: Ward anisotropic lobe with Schlick Fresnel
        h = wi + wo
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        cos_th = np.clip(h[..., 2], 1e-12, 1.0)
        tan2_th = (1.0 - cos_th ** 2) / cos_th ** 2
        hxy = np.hypot(h[..., 0], h[..., 1])
        safe = np.where(hxy > 0, hxy, 1.0)
        cos2_ph = np.where(hxy > 0, (h[..., 0] / safe) ** 2, 1.0)
        sin2_ph = 1.0 - cos2_ph
        cos_td = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
        fresnel = self.f0 + (1.0 - self.f0) * (1.0 - cos_td) ** 5
        ci = np.clip(np.cos(ti_r), 1e-6, 1.0)
        co = np.clip(np.cos(to_r), 1e-6, 1.0)
        beta_s = self.gloss_fraction * fresnel / (4.0 * self.alpha_x * self.alpha_y * np.sqrt(ci * co)) * np.exp(
            -tan2_th * (cos2_ph / self.alpha_x ** 2 + sin2_ph / self.alpha_y ** 2))
        # forward sheen and backscatter, taken from the diffuse lobe at grazing (docstring)
        u = np.sin(ti_r) * np.sin(to_r)
        rho = self.rho_d(wl)
        beta_f = self.sheen * (0.3 + 0.7 * rho) * u ** 4 * (0.5 * (1.0 - cos_dphi)) ** 2
        beta_b = self.backscatter * rho * u ** 2 * (0.5 * (1.0 + cos_dphi)) ** 4
        return beta_d * (1.0 - self.grazing_loss * u ** 2) + beta_s + beta_f + beta_b

    def describe(self) -> dict:
        """The sample and its constants as the dataset's meta records them."""
        return {"name": self.name,
                "model": "analytic Oren-Nayar + retro + Ward + sheen + backscatter (gonio.mock.samples)",
                "sigma_deg": self.sigma_deg, "retro_height": self.retro_height,
                "retro_width_deg": self.retro_width_deg, "alpha_x": self.alpha_x,
                "alpha_y": self.alpha_y, "f0": self.f0, "gloss_fraction": self.gloss_fraction,
                "sheen": self.sheen, "backscatter": self.backscatter,
                "grazing_loss": self.grazing_loss,
                "dye": {"floor": self.dye_floor, "blue_420nm": self.dye_blue,
                        "red": self.dye_red, "edge_nm": self.dye_edge_nm,
                        "edge_width_nm": self.dye_edge_width_nm}}


def _load_truth(path: str | Path, reader):
    """A sample's truth read from ``path`` by ``reader``.

    A bad file is a :class:`SampleError` naming ``path`` as the user gave it.
    """
    from gonio.data import DatasetError

    try:
        return reader(Path(path))
    except DatasetError as exc:
        raise SampleError(f"sample {path}: {exc}") from None


class DatasetSample:
    """A sample whose truth is a radiance-coefficient dataset directory (interpolated)."""

    def __init__(self, path: str | Path):
        from gonio.data import read_dataset

        self.path = Path(path)
        self.dataset = _load_truth(path, read_dataset)
        if self.dataset.is_rgb and not set("RGB") <= set(self.dataset.channels):
            raise SampleError(f"sample {path}: the dataset has channels "
                              f"{''.join(self.dataset.channels)}; the mock needs R, G and B")
        self.name = self.dataset.name

    def beta(self, theta_i, phi_i, theta_o, phi_o, wavelength_nm) -> np.ndarray:
        """Interpolated ``beta``; raises ``gonio.data.DatasetError`` outside the data."""
        if not self.dataset.is_rgb:
            return self.dataset.interpolate(theta_i, phi_i, theta_o, phi_o, wavelength_nm)[0]
        rgb = np.stack([self.dataset.interpolate(theta_i, phi_i, theta_o, phi_o, c)[0] for c in "RGB"], axis=-1)
        space = self.dataset.meta.get("colour_space") or "linear sRGB"
        if space != "linear sRGB":              # the decomposition's basis is sRGB's
            import colour

            from gonio.data.colour import colourspace

            rgb = colour.RGB_to_RGB(rgb, colourspace(space), colourspace("linear sRGB"),
                                    chromatic_adaptation_transform="Bradford")
        return rgb_spectrum(rgb, wavelength_nm)

    def describe(self) -> dict:
        """The sample as the dataset's meta records it."""
        return {"name": self.name, "model": "dataset", "path": str(self.path)}


class BSDFSample:
    """A sample whose truth is an RGL ``.bsdf`` file, evaluated at the geometry asked for."""

    def __init__(self, path: str | Path):
        from gonio.data.formats.rgl_bsdf import read_rgl_bsdf

        self.path = Path(path)
        self.bsdf = _load_truth(path, read_rgl_bsdf)
        self.name = self.path.stem

    def beta(self, theta_i, phi_i, theta_o, phi_o, wavelength_nm) -> np.ndarray:
        ti, pi_, to, po, wl = _broadcast(theta_i, phi_i, theta_o, phi_o, wavelength_nm)
        bands = self.bsdf.beta(ti, pi_, to, po)          # (..., bands)
        if self.bsdf.is_spectral:
            grid = self.bsdf.wavelengths_nm
            j = np.clip(np.searchsorted(grid, wl) - 1, 0, max(grid.size - 2, 0))
            if grid.size == 1:
                return bands[..., 0]
            f = np.clip((wl - grid[j]) / (grid[j + 1] - grid[j]), 0.0, 1.0)
            lo = np.take_along_axis(bands, j[..., None], axis=-1)[..., 0]
            hi = np.take_along_axis(bands, (j + 1)[..., None], axis=-1)[..., 0]
            return (1 - f) * lo + f * hi
        return rgb_spectrum(bands[..., :3], wl)                          # bands in R, G, B order

    def describe(self) -> dict:
        """The sample as the dataset's meta records it.

        Name, model, path, the file's own description, its SHA-256 and, for a file the project
        ships (:data:`KNOWN_FILES`), where it comes from and its licence.
        """
        import hashlib

        sha = hashlib.sha256(self.path.read_bytes()).hexdigest()
        out = {"name": self.name, "model": "RGL .bsdf (Dupuy & Jakob 2018)",
               "path": str(self.path), "description": self.bsdf.description, "sha256": sha,
               "measured_incidence_deg": [round(float(t), 4) for t in self.bsdf.theta_i_deg]}
        if sha in KNOWN_FILES:
            out["source"] = KNOWN_FILES[sha]
        return out


#: Real measurements the project ships (``fixtures/real/README.md``), by SHA-256: their source.
KNOWN_FILES = {
    "3429e2bdbe2045dca11582479fa251866ffe056b909b47e3fbf1c3c776fcb72b":
        "RGL material database, Realistic Graphics Lab, EPFL (rgl.epfl.ch/materials): a real "
        "measurement of green acrylic felt (Edukit A4), isotropic RGB, licence CC0 1.0; "
        "Dupuy & Jakob, ACM TOG 37(6), 2018",
}


def make_sample(spec: str) -> LambertSample | RedCottonSample | DatasetSample | BSDFSample:
    """Build a sample from ``lambert:RHO``, ``red-cotton`` or a dataset directory path.

    Raises
    ------
    SampleError : the specification is not understood or the dataset is unreadable.
    """
    spec = str(spec).strip()
    if spec.startswith("lambert:"):
        try:
            rho = float(spec.split(":", 1)[1])
        except ValueError:
            raise SampleError(f"sample {spec!r}: expected lambert:RHO with RHO a number in 0..1") from None
        return LambertSample(rho)
    if spec == "red-cotton":
        return RedCottonSample()
    path = Path(spec)
    if path.is_dir():
        return DatasetSample(path)
    if path.suffix == ".bsdf" and path.is_file():
        return BSDFSample(path)
    raise SampleError(f"unknown sample {spec!r}: use lambert:RHO, red-cotton, a dataset "
                      "directory or an RGL .bsdf file")
