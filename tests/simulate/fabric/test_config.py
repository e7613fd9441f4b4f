"""Simulation configs: the preset, the schema, and one clear error naming the field per bad input."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from simulate.config import ConfigError, load_config, parse_config, preset_names
from simulate.media.medium import HGMedium, MieMedium

BASE = """
name = "test"
seed = 3

[fiber]
radius_um = 8.0
n_host = 1.557
cell_width_deg = 10
route = "nee"

[fiber.dye]
curve = "gaussian-bands"
baseline_per_um = 0.001
bands = [{ center_nm = 525, width_nm = 40, peak_per_um = 1.0 }]

[particles]
n = 2.7
k = 0.0
radius_um = 0.1
volume_fraction = 0.05

[surface]
rms_slope = 0.3

[weave]
matrix = [[1, 0], [0, 1]]
spacing_um = 300

[method]
target_rel_err = 0.02
"""


def test_preset_red_cotton_loads_by_name():
    assert "red-cotton" in preset_names()
    cfg = load_config("red-cotton")
    assert cfg.name == "red-cotton" and cfg.n_host == 1.557
    assert cfg.source == "preset red-cotton"
    fiber = cfg.fiber([450.0, 550.0, 650.0])
    assert isinstance(fiber.medium, MieMedium)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the preset stays inside the models' domains
        mu_s, mu_a, g = fiber.medium.coefficients(np.array([450.0, 550.0, 650.0]))
    assert np.all(mu_s > 0) and np.all((g > 0) & (g < 1))
    # the dye: strong absorption in the green, little in the red
    assert mu_a[1] > 10 * mu_a[2]


def test_base_config_parses_to_the_fields():
    cfg = parse_config(BASE, "test.toml")
    assert (cfg.radius_um, cfg.n_host, cfg.rms_slope, cfg.seed) == (8.0, 1.557, 0.3, 3)
    assert cfg.route == "nee" and cfg.target_rel_err == 0.02
    assert cfg.max_photons is None and cfg.threads is None
    assert cfg.weave == {"matrix": [[1, 0], [0, 1]], "spacing_um": 300.0}
    dye = cfg.dye(np.array([525.0, 605.0]))
    np.testing.assert_allclose(dye, [1.001, 0.001 + np.exp(-0.5 * 4.0)], rtol=1e-12)
    assert len(cfg.wavelengths_nm) == 33


def test_exit_bins_default_and_given():
    base = parse_config(BASE, "test.toml")
    assert base.exit_bins is None          # chosen per run by the fiber (simulate.raytrace.estimate.default_exit_bins)
    cfg = parse_config(_set(BASE, "target_rel_err = 0.02", "target_rel_err = 0.02\nexit_bins = [5, 10]"), "t.toml")
    assert cfg.exit_bins == (5, 10)


def test_the_fiber_route_has_one_key():
    """The fiber route is ``[fiber] route``; a ``[method] method`` is an unknown field, refused with its name."""
    assert parse_config(_set(BASE, 'route = "nee"', 'route = "beam"'), "t.toml").route == "beam"
    with pytest.raises(ConfigError, match=r"method\.method"):
        parse_config(_set(BASE, "[method]\n", '[method]\nmethod = "beam"\n'), "t.toml")


def test_transmission_rms_slope_defaults_to_the_smooth_boundary_and_reaches_the_fiber():
    base = parse_config(BASE, "test.toml")
    assert base.transmission_rms_slope == 0.0 and base.fiber().transmission_roughness == 0.0
    cfg = parse_config(_set(BASE, "rms_slope = 0.3", "rms_slope = 0.3\ntransmission_rms_slope = 0.12"), "t.toml")
    assert cfg.fiber().transmission_roughness == 0.12 and cfg.fiber().roughness == 0.3
    assert cfg.fiber().transmission_roughness_around is None        # isotropic
    aniso = parse_config(_set(BASE, "rms_slope = 0.3", "rms_slope = 0.3\ntransmission_rms_slope = 0.05\n"
                              "transmission_rms_slope_around = 0.3"), "t.toml")
    assert (aniso.fiber().transmission_roughness, aniso.fiber().transmission_roughness_around) == (0.05, 0.3)


def test_axial_nodes_and_shift_default_to_steps_of_a_quarter_and_reach_the_grid():
    base = parse_config(BASE, "test.toml")
    assert base.w_t_nodes() == (0.0, 0.25, 0.5, 0.75, 0.95) and base.axial_shift is False
    cfg = parse_config(_set(BASE, "target_rel_err = 0.02", "target_rel_err = 0.02\naxial_nodes = 9\naxial_shift = true"),
                       "t.toml")
    nodes = np.array(cfg.w_t_nodes())
    assert nodes.size == 9 and nodes[0] == 0.0 and nodes[-1] == 0.95
    np.testing.assert_allclose(nodes[:-1], np.arange(8) / 8, atol=1e-6)     # steps of 1/(N-1), the last at 0.95
    assert cfg.axial_shift is True


def test_felt_realisations_default_to_the_constant_and_are_read():
    from simulate.config import DEFAULT_FELT_REALISATIONS

    assert parse_config(BASE, "test.toml").felt_realisations == DEFAULT_FELT_REALISATIONS
    cfg = parse_config(_set(BASE, "target_rel_err = 0.02", "target_rel_err = 0.02\nfelt_realisations = 6"), "t.toml")
    assert cfg.felt_realisations == 6


def test_hg_medium_and_tables():
    text = BASE.replace("""[particles]
n = 2.7
k = 0.0
radius_um = 0.1
volume_fraction = 0.05""", "[medium]\nmu_s = 0.5\nmu_a = 0.01\ng = 0.8").replace(
        """[fiber.dye]
curve = "gaussian-bands"
baseline_per_um = 0.001
bands = [{ center_nm = 525, width_nm = 40, peak_per_um = 1.0 }]""", "")
    cfg = parse_config(text, "hg.toml")
    med = cfg.medium()
    assert isinstance(med, HGMedium) and (med.mu_s, med.mu_a, med.g) == (0.5, 0.01, 0.8)


def test_dye_table_and_logistic_edge():
    table = BASE.replace('curve = "gaussian-bands"\nbaseline_per_um = 0.001\n'
                         'bands = [{ center_nm = 525, width_nm = 40, peak_per_um = 1.0 }]',
                         "wavelength_nm = [400, 500, 600]\nmu_a_per_um = [0.2, 0.6, 0.0]")
    cfg = parse_config(table, "t.toml")
    np.testing.assert_allclose(cfg.dye([450.0, 550.0]), [0.4, 0.3])
    edge = BASE.replace('curve = "gaussian-bands"\nbaseline_per_um = 0.001\n'
                        'bands = [{ center_nm = 525, width_nm = 40, peak_per_um = 1.0 }]',
                        'curve = "logistic-edge"\nshort_per_um = 0.5\nlong_per_um = 0.001\n'
                        'edge_nm = 590\nwidth_nm = 10')
    cfg = parse_config(edge, "e.toml")
    np.testing.assert_allclose(cfg.dye([390.0, 590.0, 800.0]), [0.5, 0.2505, 0.001], atol=1e-8)


def test_particle_spectra_and_size_distribution():
    text = BASE.replace("n = 2.7\n", "n = { wavelength_nm = [400, 700], values = [2.8, 2.6] }\n").replace(
        "radius_um = 0.1\n", "size = { median_radius_um = 0.1, sigma_g = 1.4 }\n")
    cfg = parse_config(text, "s.toml")
    med = cfg.medium([550.0])
    assert med.size_distribution.sigma_g == 1.4
    assert med.particle_index(550.0).real == pytest.approx(2.7)


def _set(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


BAD = [
    # (old, new, expected message fragment)
    ("radius_um = 8.0", 'radius_um = "abc"', 'fiber.radius_um must be a number > 0 and <= 10000, got "abc"'),
    ("radius_um = 8.0", "radius_um = -1", "fiber.radius_um must be a number > 0"),
    ("radius_um = 8.0\n", "", "fiber.radius_um is required"),
    ("n_host = 1.557", "n_host = 0.5", "fiber.n_host must be a number >= 1"),
    ("n_host = 1.557", "n_host = true", "fiber.n_host must be a number"),
    ("cell_width_deg = 10", "cell_width_deg = 0", "fiber.cell_width_deg must be a number > 0"),
    ("peak_per_um = 1.0", "peak_per_um = -1.0", "fiber.dye.bands[0].peak_per_um must be a number >= 0"),
    ('curve = "gaussian-bands"', 'curve = "rainbow"', "fiber.dye.curve must be one of gaussian-bands, logistic-edge"),
    ("n = 2.7", "n = 0", "particles.n must be a number > 0"),
    ("n = 2.7", "n = { wavelength_nm = [400, 300], values = [2, 2] }", "particles.n.wavelength_nm must be strictly increasing"),
    ("n = 2.7", "n = { wavelength_nm = [400, 500], values = [2] }", "particles.n.values must have as many items"),
    ("k = 0.0", "k = -0.1", "particles.k must be a number >= 0"),
    ("radius_um = 0.1\n", "", "particles.radius_um or particles.size: give exactly one"),
    ("radius_um = 0.1\n", "radius_um = 0.1\nsize = { median_radius_um = 0.1, sigma_g = 1.4 }\n",
     "particles.radius_um or particles.size: give exactly one"),
    ("radius_um = 0.1\n", "size = { median_radius_um = 0.1, sigma_g = 0.5 }\n", "particles.size.sigma_g must be a number >= 1"),
    ("volume_fraction = 0.05", "volume_fraction = 1.5", "particles.volume_fraction must be a number >= 0 and < 1"),
    ("volume_fraction = 0.05", "number_density_per_um3 = -3", "particles.number_density_per_um3 must be a number >= 0"),
    ("[particles]", "[medium]\nmu_s = 1\nmu_a = 0\ng = 0.5\n[particles]", "particles or medium: give exactly one"),
    ("rms_slope = 0.3", "rms_slope = 0", "surface.rms_slope must be a number > 0"),
    ("rms_slope = 0.3", "rms_slope = 0.3\nroughness = 2", "surface.roughness is not a known field"),
    ("rms_slope = 0.3", "rms_slope = 0.3\ntransmission_rms_slope = -0.1",
     "surface.transmission_rms_slope must be a number >= 0 and <= 1"),
    ("rms_slope = 0.3", "rms_slope = 0.3\ntransmission_rms_slope = \"rough\"",
     "surface.transmission_rms_slope must be a number"),
    ("rms_slope = 0.3", "rms_slope = 0.3\ntransmission_rms_slope_around = 2",
     "surface.transmission_rms_slope_around must be a number >= 0 and <= 1"),
    ("matrix = [[1, 0], [0, 1]]", "matrix = [[1, 0], [0]]", "weave.matrix must be a rectangular list of rows of 0/1"),
    ("matrix = [[1, 0], [0, 1]]", "matrix = [[1, 2], [0, 1]]", "weave.matrix must be a rectangular list"),
    ("spacing_um = 300", 'spacing_um = "wide"', "weave.spacing_um must be a number > 0"),
    ('route = "nee"', 'route = "fast"', "fiber.route must be one of nee, beam, bssrdf"),
    ("target_rel_err = 0.02", "target_rel_err = 0", "method.target_rel_err must be a number > 0 and < 1"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nmax_photons = 1.5", "method.max_photons must be an integer"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nthreads = -2", "method.threads must be an integer"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\naxial_shift = 1", "method.axial_shift must be true or false"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\naxial_nodes = 1", "method.axial_nodes must be an integer"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\naxial_nodes = 9.5", "method.axial_nodes must be an integer"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nfelt_realisations = 3",
     "method.felt_realisations must be an even integer in [2, 32]"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nfelt_realisations = 0",
     "method.felt_realisations must be an even integer in [2, 32]"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nfelt_realisations = 34",
     "method.felt_realisations must be an even integer in [2, 32]"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nfelt_realisations = 8.0",
     "method.felt_realisations must be an even integer in [2, 32]"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nfelt_realisations = true",
     "method.felt_realisations must be an even integer in [2, 32]"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nexit_bins = [5]", "method.exit_bins must be [mu bins, phi bins]"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nexit_bins = [1, 10]", "method.exit_bins must be [mu bins, phi bins]"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nexit_bins = [5, 10.5]", "method.exit_bins must be [mu bins, phi bins]"),
    ("target_rel_err = 0.02", "target_rel_err = 0.02\nexit_bins = [5, 80]", "method.exit_bins must be [mu bins, phi bins]"),
    ("seed = 3", "seed = -1", "seed must be an integer in [0,"),
    ("seed = 3", 'seed = "x"', "seed must be an integer"),
    ('name = "test"', 'name = "test"\nfabric = 1', "fabric is not a known field"),
    ("[fiber.dye]", "[fibre.dye]", "fibre is not a known field"),
    ("[fiber]\nradius_um = 8.0", "[fiber]\nradius_um = 8.0\nradius = 8", "fiber.radius is not a known field"),
]


@pytest.mark.parametrize("old,new,expected", BAD, ids=[b[2][:40] for b in BAD])
def test_bad_field_is_one_error_naming_file_and_field(old, new, expected):
    with pytest.raises(ConfigError) as info:
        parse_config(_set(BASE, old, new), "/some/dir/red.toml")
    message = str(info.value)
    assert message.startswith("red.toml: "), message
    assert expected in message, message
    assert "\n" not in message


def test_exact_message_for_a_non_number():
    with pytest.raises(ConfigError, match=re.escape(
            'red.toml: fiber.radius_um must be a number > 0 and <= 10000, got "abc"')):
        parse_config(_set(BASE, "radius_um = 8.0", 'radius_um = "abc"'), "red.toml")


def test_dye_with_hg_medium_is_refused():
    text = _set(BASE, "[particles]\nn = 2.7\nk = 0.0\nradius_um = 0.1\nvolume_fraction = 0.05",
                "[medium]\nmu_s = 1\nmu_a = 0\ng = 0.5")
    with pytest.raises(ConfigError, match="fiber.dye cannot be combined with"):
        parse_config(text, "hg.toml")


def test_missing_fiber_table():
    with pytest.raises(ConfigError, match=r"^x.toml: fiber is required$"):
        parse_config("[surface]\nrms_slope = 0.3\n", "x.toml")


def test_invalid_toml_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match=r"^bad.toml: invalid TOML"):
        parse_config("[fiber\nradius_um = 1", "bad.toml")
    with pytest.raises(ConfigError, match="no such config file and no preset"):
        load_config(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not UTF-8"):
        parse_config(b"\xff\xfe", "bin.toml")


_values = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5),
                    st.lists(st.integers(-2, 2), max_size=3))
_FIELDS = ["radius_um = 8.0", "n_host = 1.557", "n = 2.7", "k = 0.0", "radius_um = 0.1",
           "volume_fraction = 0.05", "rms_slope = 0.3", "spacing_um = 300", "target_rel_err = 0.02",
           "seed = 3", "peak_per_um = 1.0", "matrix = [[1, 0], [0, 1]]"]


def _toml_value(v) -> str:
    if v is None:
        return '""'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if v != v:
            return "nan"
        if v in (float("inf"), float("-inf")):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return '"' + "".join(c if c.isalnum() else "_" for c in v) + '"'
    if isinstance(v, list):
        return "[" + ", ".join(str(x) for x in v) + "]"
    return str(v)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(field=st.sampled_from(_FIELDS), value=_values)
def test_fuzzed_values_give_a_config_or_one_clear_error(field, value):
    key = field.split(" = ")[0]
    text = BASE.replace(field, f"{key} = {_toml_value(value)}", 1)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cfg = parse_config(text, "fuzz.toml")
            cfg.fiber([550.0])
    except ConfigError as exc:
        assert str(exc).startswith("fuzz.toml: ") and "\n" not in str(exc)
