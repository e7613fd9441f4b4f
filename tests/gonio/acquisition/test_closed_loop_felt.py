"""Closed loop on a real material: the mock measures the RGL felt; the dataset recovers the
file's own values within the stated uncertainties."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gonio.data import read_dataset
from gonio.data.formats.rgl_bsdf import read_rgl_bsdf
from gonio.mock import MockInstrument

FELT = Path(__file__).resolve().parents[3] / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"


def test_felt_closed_loop(drv, tmp_path):
    # 450/550/650 nm fall in the B/G/R bands of the mock's three-band view of RGB samples
    plan = drv.write_plan(tmp_path, "felt", incidence=(0, 40), in_plane=(-50, -20, 10, 30, 60),
                          wavelengths=(450, 550, 650))
    with MockInstrument(sample=str(FELT), modbus="tcp", serial="pty", speed="fast",
                        seed=3) as mock:
        result = drv.run(mock, plan, tmp_path / "run")
        assert result.exit_code == 0
    ds = read_dataset(tmp_path / "run")
    truth_rgb = read_rgl_bsdf(FELT).beta(*(ds.table[c].to_numpy() for c in
                                           ("theta_i", "phi_i", "theta_o", "phi_o")))
    channel = {450.0: 2, 550.0: 1, 650.0: 0}
    truth = truth_rgb[np.arange(len(ds.table)), [channel[w] for w in ds.table.wavelength_nm]]
    z = (ds.table.beta.to_numpy() - truth) / ds.table.u_beta.to_numpy()
    # 30 values; |z| < 5 for all (false alarm ~2e-5 for independent normal z)
    assert np.all(np.abs(z) < 5), z
    # green felt: at every geometry the 550 nm value exceeds the 650 nm one, which exceeds 450 nm
    piv = ds.table.pivot_table(index=["theta_i", "theta_o", "phi_o"], columns="wavelength_nm",
                               values="beta")
    assert np.all(piv[550.0] > piv[650.0]) and np.all(piv[650.0] > piv[450.0])
