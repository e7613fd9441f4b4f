"""A stand-in fiber BRDF with a known analytic form, for testing the fabric layer's own logic.

The fake replaces :func:`simulate.fiber.volume_brdf`, :func:`~simulate.fiber.surface_brdf` and
:func:`~simulate.fiber.normal_albedo` (only in the tests that ask for the ``fake_fiber`` fixture):

    R_vol(w_in, w_out, lambda) = rho(lambda) / pi * max(cos_in, 0)
                                 * (1 + A w_in,x^2 + B w_out,y^2 + C w_in,x w_out,x + D w_in,y w_out,y)

anisotropic (warp and weft differ, the fiber axis x is singled out) but symmetric under the two
mirrors ``x -> -x`` and ``y -> -y`` applied to both directions, as the real fiber BRDF is. With
A = B = C = D = 0 it is Lambertian with albedo rho. ``u_R = REL_ERR * R``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

REL_ERR = 0.02
PHOTONS = 12345


def fake_rho(wavelengths_nm) -> np.ndarray:
    """A red-ish albedo spectrum in (0, 1)."""
    wl = np.asarray(wavelengths_nm, float)
    return 0.05 + 0.5 / (1.0 + np.exp(-(wl - 600.0) / 15.0))


def fake_R(w_in, w_out, wavelengths_nm, a=0.3, b=0.2, c=0.25, d=-0.15) -> np.ndarray:
    w_in = np.atleast_2d(w_in)
    w_out = np.atleast_2d(w_out)
    shape = (1.0 + a * w_in[:, 0] ** 2 + b * w_out[:, 1] ** 2 + c * w_in[:, 0] * w_out[:, 0]
             + d * w_in[:, 1] * w_out[:, 1])
    cos_in = np.clip(w_in[:, 2], 0.0, None)
    return (cos_in * shape)[:, None] * fake_rho(wavelengths_nm)[None, :] / np.pi


def fake_surface(w_in, w_out, m=0.35, n_host=1.557) -> np.ndarray:
    from simulate.optics.microfacet import cook_torrance

    return cook_torrance(w_in, w_out, m, n_host) * np.clip(np.atleast_2d(w_in)[:, 2], 0.0, None)


@dataclass
class FakeFiber:
    """Records the calls made to the fake fiber functions."""

    volume_calls: list = field(default_factory=list)
    albedo_calls: list = field(default_factory=list)
    surface_calls: int = 0


@pytest.fixture
def fake_fiber(monkeypatch):
    from simulate import fiber as fiber_mod

    rec = FakeFiber()

    def volume_brdf(fiber, w_in, w_out, wavelengths_nm, *, method="nee", target_rel_err=0.01,
                    max_photons=None, seed=0, threads=None, progress=False):
        rec.volume_calls.append({"w_in": np.array(w_in), "w_out": np.array(w_out),
                                 "wavelengths_nm": np.array(wavelengths_nm), "method": method,
                                 "target_rel_err": target_rel_err, "seed": seed})
        R = fake_R(w_in, w_out, wavelengths_nm)
        return fiber_mod.BRDFEstimate(R=R, u_R=REL_ERR * R, photons=PHOTONS, seconds=0.01,
                                      info={"method": method, "rel_err": REL_ERR,
                                            "array": np.arange(3)})

    def surface_brdf(fiber, w_in, w_out):
        rec.surface_calls += 1
        return fake_surface(w_in, w_out, fiber.roughness, fiber.n_host)

    def normal_albedo(fiber, wavelengths_nm, *, target_rel_err=0.01, seed=0, threads=None):
        rec.albedo_calls.append({"wavelengths_nm": np.array(wavelengths_nm), "seed": seed})
        rho = fake_rho(wavelengths_nm)
        return rho, REL_ERR * rho

    monkeypatch.setattr(fiber_mod, "volume_brdf", volume_brdf)
    monkeypatch.setattr(fiber_mod, "surface_brdf", surface_brdf)
    monkeypatch.setattr(fiber_mod, "normal_albedo", normal_albedo)
    # the fiber-table module imports the two functions by name (simulate fiber's path)
    from simulate.fiber import tables

    monkeypatch.setattr(tables, "volume_brdf", volume_brdf)
    monkeypatch.setattr(tables, "surface_brdf", surface_brdf)
    return rec


def carpet_text() -> str:
    """The red-cotton preset without its ``[structure]`` section: the carpet of top cells, the
    summation route these fake-fiber tests exercise (docs/physics.md section 6)."""
    import re

    from simulate.config import resolve_config_path

    text = resolve_config_path("red-cotton").read_text()
    carpet = re.sub(r"(?ms)^\[structure\]\n.*?(?=^\[|\Z)", "", text)
    assert not re.search(r"(?m)^\[structure\]", carpet) and "[weave]" in carpet
    return carpet


def carpet_config():
    """:func:`carpet_text` parsed (name ``red-cotton``)."""
    from simulate.config import parse_config

    return parse_config(carpet_text(), "red-cotton-carpet.toml")


@pytest.fixture
def carpet_path(tmp_path):
    """:func:`carpet_text` as a config file."""
    path = tmp_path / "red-cotton-carpet.toml"
    path.write_text(carpet_text())
    return path
