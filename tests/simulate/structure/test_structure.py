"""Fibers in all their orientations (simulate.fabric.structure), the interior closure and the [structure] config."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gonio.acquisition.plan import parse_plan
from simulate.config import ConfigError, parse_config
from simulate.fabric import interior as IN
from simulate.fabric import structure as ST
from simulate.fiber import Fiber
from simulate.fiber import farfield as FF
from simulate.geometry import weave as WV
from simulate.media.medium import HGMedium

HG_CONFIG = """
name = "hg"
seed = 3
[fiber]
radius_um = 10.0
n_host = 1.5
[medium]
mu_s = 0.4
mu_a = 0.02
g = 0.5
[surface]
rms_slope = 0.3
[weave]
matrix = [[1, 0], [0, 1]]
spacing_um = 300
width_um = 250
height_um = 100
"""

TINY_PLAN = ('[sample]\nname = "x"\n[wavelengths]\nlist_nm = [550, 650]\n'
             '[geometry]\nincidence_deg = [0, 45]\nin_plane_deg = [-30, 10, 40]\n')


@pytest.mark.parametrize("line,field", [
    ('kind = "knit"', "structure.kind"),
    ('kind = "felt"', "structure.kind"),
    ('layers = -1', "structure.layers"),
    ('packing_fraction = 0.95', "structure.packing_fraction"),
    ('packing_fraction = 0', "structure.packing_fraction"),
    ('warp_twist_deg = 75', "structure.warp_twist_deg"),
    ('warp_twist = "X"', "structure.warp_twist"),
    ('weft_twist_deg = "a"', "structure.weft_twist_deg"),
    ('weft_twist = "z"', "structure.weft_twist"),
    ('felt_spread_deg = -5', "structure.felt_spread_deg"),
    ('kind = "nonwoven"\nfelt_normal_fraction = 0.95', "structure.felt_normal_fraction"),
    ('kind = "nonwoven"\nfelt_normal_fraction = -0.1', "structure.felt_normal_fraction"),
    ('kind = "nonwoven"\nfelt_normal_fraction = "some"', "structure.felt_normal_fraction"),
    ('kind = "nonwoven"\nfelt_normal_spread_deg = 50', "structure.felt_normal_spread_deg"),
    ('kind = "nonwoven"\nfelt_normal_spread_deg = true', "structure.felt_normal_spread_deg"),
    ('felt_normal_fraction = 0.2', "structure.felt_normal_fraction"),
    ('kind = "nonwoven"\nfelt_crimp_percent = 45', "structure.felt_crimp_percent"),
    ('kind = "nonwoven"\nfelt_crimp_percent = -1', "structure.felt_crimp_percent"),
    ('kind = "nonwoven"\nfelt_crimp_percent = "lots"', "structure.felt_crimp_percent"),
    ('kind = "nonwoven"\nfelt_crimp_per_cm = 0', "structure.felt_crimp_per_cm"),
    ('kind = "nonwoven"\nfelt_crimp_per_cm = 25', "structure.felt_crimp_per_cm"),
    ('kind = "nonwoven"\nfelt_crimp_per_cm = nan', "structure.felt_crimp_per_cm"),
    ('kind = "nonwoven"\nfelt_crimp_plane = "vertical"', "structure.felt_crimp_plane"),
    ('kind = "nonwoven"\nfelt_crimp_plane = 1', "structure.felt_crimp_plane"),
    ('felt_crimp_percent = 10', "structure.felt_crimp_percent"),
    ('felt_crimp_plane = "felt"', "structure.felt_crimp_plane"),
    ('samples = 2', "structure.samples"),
    ('twist = 3', "structure.twist"),
])
def test_every_structure_field_is_validated(line, field):
    with pytest.raises(ConfigError) as exc:
        parse_config(HG_CONFIG + "[structure]\n" + line + "\n", "bad.toml")
    message = str(exc.value)
    assert message.startswith(f"bad.toml: {field}") and "\n" not in message


def test_bad_structure_field_is_one_line_exit_2(tmp_path, capsys):
    from fabric_optics.cli.simulate import main

    path = tmp_path / "bad.toml"
    path.write_text(HG_CONFIG + "[structure]\nwarp_twist = \"Q\"\n")
    assert main(["fabric", str(path), "--method", "summation", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "structure.warp_twist" in err[0]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("line", ['cells = "top"', "masking = false", "yarn_surface = true", "interior = true",
                                  'interior_return = "diffuse"'])
def test_a_removed_structure_key_is_one_line_exit_2(tmp_path, capsys, line):
    """A switch that was removed (its model is always on) is refused by name, with what to do, exit 2 --
    whatever value it has, and before any other field is read."""
    from fabric_optics.cli.simulate import main

    key = line.split(" =")[0]
    path = tmp_path / "old.toml"
    path.write_text(HG_CONFIG + "[structure]\nwarp_twist = \"Q\"\n" + line + "\n")
    assert main(["fabric", str(path), "--method", "summation", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"old.toml: structure.{key} was removed; " in err[0] and "delete the line" in err[0]
    assert not (tmp_path / "o").exists()


def test_the_felt_alias_is_refused_with_its_replacement():
    with pytest.raises(ConfigError, match='structure.kind value "felt" was removed; write kind = "nonwoven"'):
        parse_config(HG_CONFIG + '[structure]\nkind = "felt"\n', "old.toml")
    assert parse_config(HG_CONFIG + '[structure]\nkind = "nonwoven"\n', "new.toml").structure.kind == "nonwoven"


def test_defaults_from_the_literature():
    spec = parse_config(HG_CONFIG + "[structure]\n", "hg.toml").structure
    assert (spec.kind, spec.warp_twist, spec.warp_twist_deg) == ("woven", "Z", 24.0)
    assert spec.spacing_ratio == pytest.approx(1.0)


def test_woven_facets_geometry():
    """Plain weave: warp and weft half each, the corner holes (1 - w/p)^2, fibers at the twist angle to the yarn."""
    weave = WV.Weave([[1, 0], [0, 1]], spacing_um=300, width_um=250, height_um=100)
    spec = ST.StructureSpec(warp_twist_deg=30.0, weft_twist_deg=30.0, samples=96)
    f = ST.woven_facets(weave, spec)
    assert f.visible_fraction(0) == pytest.approx(0.5, abs=0.01)
    assert f.info["holes"] == pytest.approx((1 - 250 / 300) ** 2, abs=0.005)
    t, m = f.M[:, 0], f.M[:, 2]
    assert np.allclose(np.einsum("ki,ki->k", t, m), 0.0, atol=1e-12)
    # untwisted, the fiber is the yarn tangent: the angle between twisted and untwisted fibers is the twist
    plain = ST.woven_facets(weave, ST.StructureSpec(warp_twist_deg=0.0, weft_twist_deg=0.0, samples=96))
    cos = np.einsum("ki,ki->k", t, plain.M[:, 0])
    assert np.allclose(cos, math.cos(math.radians(30.0)), atol=1e-12)
    # the crimp tilts the surface: some normals leave the vertical by more than the spline's slope alone
    assert f.info["max_inclination_deg"] > 30.0
    # Z: on the crown of a warp (m = z, T = x) the fiber runs along (cos a, -sin a, 0), the middle stroke of a Z
    flat = ST.flat_facets(ST.StructureSpec(warp_twist_deg=30.0))
    assert np.allclose(flat.M[0, 0], [math.cos(math.radians(30)), -math.sin(math.radians(30)), 0.0])
    s_twist = ST.flat_facets(ST.StructureSpec(warp_twist_deg=30.0, warp_twist="S"))
    assert np.allclose(s_twist.M[0, 0], [math.cos(math.radians(30)), math.sin(math.radians(30)), 0.0])


def test_felt_facets_are_an_isotropic_spread():
    f = ST.felt_facets(ST.StructureSpec(kind="nonwoven", felt_spread_deg=15.0))
    assert f.a.sum() == pytest.approx(1.0)
    incl = np.degrees(np.arcsin(f.M[:, 0, 2]))
    assert math.sqrt(np.sum(f.a * incl ** 2)) == pytest.approx(15.0, rel=0.02)
    az = np.arctan2(f.M[:, 0, 1], f.M[:, 0, 0])
    assert abs(np.sum(f.a * np.exp(2j * az))) < 1e-9           # no preferred in-plane direction


def test_lambertian_layers_give_a_lambertian_fabric_and_felt_is_isotropic():
    """G = rho/pi (w_i.m)(w_o.m) on flat facets: beta = rho exactly; felt beta does not depend on the sample rotation."""
    def lambert(li, lo):
        return (0.6 / math.pi * np.clip(li[:, 2], 0, None) * np.clip(lo[:, 2], 0, None))[:, None]

    w_i = np.array([[math.sin(0.5), 0.0, math.cos(0.5)]])
    w_o = np.array([[-0.3, 0.2, math.sqrt(1 - 0.13)]])
    assert ST.fabric_beta_from_G(lambert, ST.flat_facets(ST.StructureSpec()), w_i, w_o)[0, 0] == pytest.approx(0.6)

    def anisotropic(li, lo):   # depends on the fiber direction: a felt averages it out over azimuth
        return (np.clip(li[:, 2], 0, None) * np.clip(lo[:, 2], 0, None) * (1.0 + li[:, 0] ** 2))[:, None]

    felt = ST.felt_facets(ST.StructureSpec(kind="nonwoven"))
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    a = ST.fabric_beta_from_G(anisotropic, felt, w_i, w_o)[0, 0]
    b = ST.fabric_beta_from_G(anisotropic, felt, w_i @ rot.T, w_o @ rot.T)[0, 0]
    assert a == pytest.approx(b, rel=1e-9)


def test_stack_reflectance_tends_to_the_kubelka_limit():
    r, t = np.array([0.3, 0.5]), np.array([0.4, 0.3])
    a = 1.0 + r ** 2 - t ** 2
    r_inf = (a - np.sqrt(a ** 2 - 4 * r ** 2)) / (2 * r)          # Kubelka (1948), infinitely thick pile
    assert np.allclose(IN.stack_reflectance(r, t, 2000), r_inf, rtol=1e-9)
    assert np.allclose(IN.stack_reflectance(r, t, 1), r)
    assert np.allclose(IN.stack_reflectance(r, t, 2), r + t * t * r / (1 - r * r))


def test_interior_closure_conserves_energy_for_a_white_fiber():
    """Non-absorbing fiber, a thick fabric: every photon comes back out (the layer albedo with the closure -> 1)."""
    fiber = Fiber(radius_um=10.0, n_host=1.5, medium=HGMedium(mu_s=0.4, mu_a=0.0, g=0.5), roughness=0.3,
                  cell_width_deg=10)
    table = FF.exit_table(fiber, [550.0], w_t=[0.0, 0.5, 0.9], photons_per_row=3_000, seed=1, threads=2)
    inner = IN.interior(table, fiber, 5000)
    assert inner.k[0] > 0.1 and inner.t[0] > 0.05     # masking and transmission both matter for this layer
    w_in = np.array([math.sin(0.4), 0.0, math.cos(0.4)])
    energy = IN.layer_energy(table, fiber, w_in, inner.classes)
    u, d, e, gap = energy[:, 0]
    assert e == pytest.approx(1.0, abs=0.005)         # the white fiber's light all leaves it
    assert gap == pytest.approx(0.0, abs=1e-9)        # touching fibers: nothing passes between them
    total = u + inner.returned(energy)[0]
    # an infinitely thick white pile returns everything; the per-interaction balance r + t + k is 1 to
    # the table's noise (~1e-3), and a pile amplifies a loss a to 1 - R ~ sqrt(2 a / r): hence 0.93
    assert inner.r[0] + inner.t[0] + inner.k[0] == pytest.approx(1.0, abs=0.003)
    assert 0.93 <= total <= 1.005
    assert u < 0.6                                    # without the closure most of it would be missing


def test_structured_summation_dataset_end_to_end(tmp_path):
    """`--method summation` with [structure]: a dataset with errors, its structure in the metadata, the twist on."""
    from gonio.data.dataset import read_dataset, write_dataset
    from simulate.virtual import fabric_dataset

    cfg = parse_config(HG_CONFIG + "[structure]\nwarp_twist_deg = 20\nweft_twist = \"S\"\n", "hg.toml")
    plan = parse_plan(TINY_PLAN, "tiny.toml")
    ds = fabric_dataset(cfg, plan, "summation", target_rel_err=0.2, seed=1, threads=2)
    write_dataset(ds, tmp_path / "d")
    t = read_dataset(tmp_path / "d").table
    assert len(t) == len(plan.geometries()) * 2
    assert np.all(t["beta"] > 0) and np.all(t["u_beta"] > 0) and np.all(t["u_beta"] < 0.3 * t["beta"])
    model = ds.meta["model"]
    assert model["structure"]["warp_twist_deg"] == 20.0 and model["structure"]["weft_twist"] == "S"
    assert 0.45 < model["facets"]["warp"] < 0.55
