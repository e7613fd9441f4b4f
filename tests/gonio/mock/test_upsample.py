"""The mock's spectra for RGB samples (gonio.mock.upsample): the file's colour, linear, physical."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.data.colour import spectrum_to_rgb
from gonio.mock.samples import make_sample
from gonio.mock.upsample import basis, rgb_spectrum

FINE = np.arange(380.0, 781.0, 5.0)


@pytest.mark.parametrize("rgb", [(0.1816, 0.305, 0.0476), (1.175, 1.463, 0.373), (0.8, 0.0088, 0.064),
                                 (0.02, 0.02, 0.02), (0.0, 0.3, 0.0)])
def test_the_spectrum_has_the_rgb_colour(rgb):
    # CIE 1931 / D65 / linear sRGB through colour-science (the colour match's pipeline), an
    # independent path from the basis table
    back = spectrum_to_rgb(FINE, rgb_spectrum(np.array(rgb), FINE))
    assert np.allclose(back, rgb, atol=2e-4), back


def test_the_basis_file_is_colour_sciences_table():
    from colour.recovery import MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019 as table

    assert np.array_equal(basis(table.wavelengths), np.asarray(table.values, dtype=float))
    assert np.array_equal(basis(np.array([300.0, 900.0])), np.asarray(table.values, dtype=float)[[0, -1]])


def test_basis_is_a_partition_of_white_and_non_negative():
    b = basis(np.arange(360.0, 831.0, 1.0))
    assert np.all(b >= 0.0)
    assert np.allclose(b.sum(axis=-1), 1.0, atol=2e-3)     # grey stays flat
    grey = rgb_spectrum(np.array([0.4, 0.4, 0.4]), FINE)
    assert np.allclose(grey, 0.4, atol=1e-3)


def test_broadcasting_and_clipping():
    rgb = np.array([[0.2, 0.5, 0.1], [0.6, 0.1, -0.05]])          # a negative channel is noise: clipped
    wl = np.array([[450.0], [550.0], [650.0]])                   # (3, 1) against (2,): (3, 2)
    out = rgb_spectrum(rgb, wl)
    assert out.shape == (3, 2)
    assert np.allclose(out[:, 1], rgb_spectrum(np.array([0.6, 0.1, 0.0]), wl[:, 0]))
    # a green's spectrum peaks in the green, a red's in the red
    assert np.argmax(out[:, 0]) == 1 and np.argmax(out[:, 1]) == 2


def test_rgb_dataset_sample_answers_with_the_decomposition(tmp_path):
    import pandas as pd

    from gonio.data import make_dataset, new_meta, write_dataset

    rows = [{"theta_i": 0.0, "phi_i": 0.0, "theta_o": to, "phi_o": 0.0, "channel": c, "beta": v,
             "u_beta": 0.001, "n": 1} for to in (10.0, 20.0, 30.0)
            for c, v in zip("RGB", (0.2, 0.5, 0.1), strict=True)]
    ds = make_dataset(pd.DataFrame(rows), new_meta("measured", {"name": "rgb"}, colour_space="linear sRGB"))
    write_dataset(ds, tmp_path / "rgb")
    sample = make_sample(str(tmp_path / "rgb"))
    beta = sample.beta(np.full(FINE.size, 0.0), 0.0, 20.0, 0.0, FINE)
    assert np.allclose(spectrum_to_rgb(FINE, beta), (0.2, 0.5, 0.1), atol=2e-4)
