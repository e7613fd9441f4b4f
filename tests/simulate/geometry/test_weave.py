"""simulate.geometry.weave: the Weave's validation, presets, centre-line splines and crossing heights."""

from __future__ import annotations

import numpy as np
import pytest

from simulate.geometry.weave import PRESETS, Weave, WeaveError, preset

DIMS = dict(spacing_um=300.0, width_um=250.0, height_um=100.0)


@pytest.fixture(params=sorted(PRESETS))
def weave(request):
    return preset(request.param, **DIMS)


def test_fields_properties_and_dtype():
    w = Weave([[1, 0, 1], [0, 1, 0]], spacing_um=200, width_um=150, height_um=60, crimp=0.5)
    assert w.matrix.dtype == np.int8 and w.matrix.shape == (2, 3)
    assert (w.n_warp, w.n_weft, w.n_yarns) == (2, 3, 5)
    assert (w.Lx, w.Ly) == (600.0, 400.0)
    assert (w.points_per_span, w.sides, w.crimp) == (16, 48, 0.5)
    assert not w.matrix.flags.writeable            # frozen all the way down
    assert w == Weave(np.array([[1, 0, 1], [0, 1, 0]]), spacing_um=200, width_um=150, height_um=60, crimp=0.5)
    assert hash(w) == hash(Weave(w.matrix, spacing_um=200, width_um=150, height_um=60, crimp=0.5))
    assert w != Weave(w.matrix, spacing_um=200, width_um=150, height_um=60)


@pytest.mark.parametrize("matrix,message", [
    ([[1, 0], [0, 2]], "weave matrix: entry at row 1, column 1 must be 0 or 1, got 2"),
    ([[1, 0, 1], [0, 1, 0.5]], "entry at row 1, column 2 must be 0 or 1"),
    ([[1, 0], [0, True]], "entry at row 1, column 1 must be 0 or 1"),
    ([[1, "0"], [0, 1]], "entry at row 0, column 1 must be 0 or 1"),
    ([[1, 0], [0, 1, 1]], "row 1 has 3 entries, row 0 has 2 (the matrix must be rectangular)"),
    ([], "weave matrix: is empty"),
    ([1, 0], "must be a list of rows"),
    (np.zeros(4), "must be 2-D"),
    ([[1, 0], [1, 1], [0, 1]], "weave matrix: warp row 1 never interlaces (all 1)"),
    ([[1, 0, 0], [0, 1, 0]], "weave matrix: weft column 2 never interlaces (all 0)"),
    ([[1], [0]], "warp row 0 never interlaces (all 1)"),
])
def test_bad_matrix_is_one_error_naming_row_and_column(matrix, message):
    with pytest.raises(WeaveError) as exc:
        Weave(matrix, **DIMS)
    assert message in str(exc.value)
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("field,value,message", [
    ("spacing_um", 0, "weave spacing_um must be a finite number > 0, got 0"),
    ("height_um", -1.0, "weave height_um must be a finite number > 0"),
    ("width_um", float("nan"), "weave width_um must be a finite number > 0"),
    ("width_um", 301.0, "weave width_um (301) must be <= spacing_um (300)"),
    ("crimp", 0.0, "weave crimp must be a finite number > 0"),
    ("crimp", 1.5, "weave crimp must be in (0, 1]"),
    ("points_per_span", 0, "weave points_per_span must be an integer in [1, 100000]"),
    ("points_per_span", 2.0, "weave points_per_span must be an integer"),
    ("sides", 2, "weave sides must be an integer in [3, 100000]"),
])
def test_bad_field_is_one_error_naming_it(field, value, message):
    with pytest.raises(WeaveError, match=None) as exc:
        Weave([[1, 0], [0, 1]], **{**DIMS, field: value})
    assert message in str(exc.value)


def test_width_equal_to_spacing_is_allowed():
    assert Weave([[1, 0], [0, 1]], spacing_um=300, width_um=300, height_um=100).width_um == 300.0


def test_presets_interlace_and_have_the_documented_patterns():
    for name in PRESETS:
        m = preset(name).matrix
        assert (m.min(axis=1) == 0).all() and (m.max(axis=1) == 1).all(), name
        assert (m.min(axis=0) == 0).all() and (m.max(axis=0) == 1).all(), name
    assert preset("plain").matrix.tolist() == [[1, 0], [0, 1]]
    assert preset("twill").matrix.tolist() == [[1, 1, 0, 0], [0, 1, 1, 0], [0, 0, 1, 1], [1, 0, 0, 1]]
    satin = preset("satin").matrix
    assert satin.shape == (5, 5)
    # warp-faced 5-end satin, move 2: warp j is under weft 2j mod 5 only, each weft bound once
    assert ((satin == 0).sum(axis=1) == 1).all() and ((satin == 0).sum(axis=0) == 1).all()
    assert [int(np.flatnonzero(row == 0)[0]) for row in satin] == [0, 2, 4, 1, 3]


def test_preset_passes_params_and_rejects_unknown_names():
    w = preset("twill", spacing_um=200, width_um=180, height_um=50, crimp=0.8, sides=6)
    assert (w.spacing_um, w.width_um, w.height_um, w.crimp, w.sides) == (200.0, 180.0, 50.0, 0.8, 6)
    with pytest.raises(WeaveError, match="unknown weave preset 'basket'; choose one of plain, twill, satin"):
        preset("basket")


def test_spline_passes_through_the_control_points_and_is_periodic(weave):
    amp = 0.5 * weave.crimp * weave.height_um
    for yarn in range(weave.n_yarns):
        spline = weave.centre_line(yarn)
        s, z = weave.control_points(yarn)
        L = weave.yarn_length(yarn)
        assert s[-1] - s[0] == pytest.approx(L)
        np.testing.assert_allclose(spline(s), z, atol=1e-12)
        assert set(np.abs(z)) == {amp}
        for d in (0, 1, 2):
            assert spline(s[0], d) == pytest.approx(spline(s[-1], d), abs=1e-9)
            assert spline(0.0, d) == pytest.approx(spline(L, d), abs=1e-9)      # the micro-element faces
        # periodic extrapolation: the whole run [0, L] is one period of the spline
        t = np.linspace(0.0, L, 17)
        np.testing.assert_allclose(spline(t), spline(t + L), atol=1e-9)


def test_control_points_follow_the_matrix():
    w = Weave([[1, 0, 0], [0, 1, 1]], spacing_um=100, width_um=80, height_um=40, crimp=0.5)
    s, z = w.control_points(0)                      # warp 0
    np.testing.assert_allclose(s, [50, 150, 250, 350])
    np.testing.assert_allclose(z, [10, -10, -10, 10])
    s, z = w.control_points(w.n_warp + 1)           # weft 1: over warp 0, under warp 1
    np.testing.assert_allclose(s, [50, 150, 250])
    np.testing.assert_allclose(z, [10, -10, 10])
    with pytest.raises(IndexError):
        w.centre_line(5)


def test_crossing_heights_respect_the_matrix(weave):
    m = weave.matrix
    for j in range(weave.n_warp):
        warp = weave.centre_line(j)
        for i in range(weave.n_weft):
            weft = weave.centre_line(weave.n_warp + i)
            x_i, y_j = (i + 0.5) * weave.spacing_um, (j + 0.5) * weave.spacing_um
            assert (float(warp(x_i)) > float(weft(y_j))) == (m[j, i] == 1), (j, i)
