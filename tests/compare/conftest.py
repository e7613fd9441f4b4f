"""Shared helpers for the compare tests: analytic datasets in memory and on disk."""

from __future__ import annotations

import json
import types
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gonio.data import in_plane_geometry, make_dataset, new_meta, write_dataset

REPO = Path(__file__).resolve().parents[2]
FIXTURES = REPO / "fixtures" / "analytic"
WAVELENGTHS = np.arange(390.0, 711.0, 10.0)
S_GRID = np.arange(-60.0, 71.0, 10.0)
INCIDENCE = (0.0, 30.0, 45.0, 60.0)


def in_plane_table(beta_fn, *, incidence=INCIDENCE, s_grid=S_GRID, wavelengths=WAVELENGTHS,
                   block_deg=5.0, u_fn=None, extra_s=()) -> pd.DataFrame:
    """A dataset table on in-plane geometries; ``beta_fn(theta_i, s, wavelength) -> beta``."""
    rows = []
    for theta_i in incidence:
        s = np.asarray(s_grid, float)
        s = s[np.abs(s + theta_i) >= block_deg]
        s = np.unique(np.concatenate([s, [x for x in extra_s if theta_i == 0.0]]))
        for s_deg in s:
            theta_o, phi_o = in_plane_geometry(theta_i, s_deg, 0.0)
            for wl in wavelengths:
                rows.append((theta_i, 0.0, theta_o, phi_o, wl, s_deg))
    t = pd.DataFrame(rows, columns=["theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm", "s"])
    t["beta"] = beta_fn(t["theta_i"].to_numpy(), t["s"].to_numpy(), t["wavelength_nm"].to_numpy())
    t["u_beta"] = (u_fn(t["beta"].to_numpy()) if u_fn else 0.001 + 0.0 * t["beta"])
    t["n"] = 10
    return t.drop(columns="s")


def dataset(table, kind="measured", name="sample", **sample):
    return make_dataset(table, new_meta(kind, {"name": name, **sample}, {"name": "test"},
                                        {"test": True}, created="2026-01-01T00:00:00+00:00"))


def rho(wl):
    """Independent copy of the fixtures' red dye (fixtures/analytic/README.md)."""
    return 0.04 + 0.56 / (1.0 + np.exp(-(np.asarray(wl, float) - 600.0) / 10.0))


def lobe_in_plane(theta_i, s):
    """L(alpha), alpha = |s - theta_i| in the plane of incidence (README.md)."""
    return np.maximum(0.0, 1.0 - ((np.asarray(s, float) - theta_i) / 40.0) ** 2)


def red_lobe(theta_i, s, wl):
    return rho(wl) + 0.2 * lobe_in_plane(theta_i, s)


def unprotect(directory: Path) -> None:
    """Drop the checksum from meta.json so that a deliberately corrupted CSV reaches validation."""
    meta_path = directory / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta.pop("files", None)
    meta_path.write_text(json.dumps(meta))


@pytest.fixture
def write(tmp_path):
    """write(ds, name) -> directory holding the dataset."""
    def _write(ds, name):
        return write_dataset(ds, tmp_path / name)
    return _write


def run_cli(argv, capsys):
    """Run fabric_optics.cli.compare.main in-process; return (status, stdout, stderr)."""
    from fabric_optics.cli.compare import main

    status = main([str(a) for a in argv])
    out = capsys.readouterr()
    return status, out.out, out.err


@pytest.fixture(scope="session")
def h():
    """The helpers above as one namespace (test modules cannot import conftest in importlib mode)."""
    return types.SimpleNamespace(
        in_plane_table=in_plane_table, dataset=dataset, rho=rho, lobe_in_plane=lobe_in_plane,
        red_lobe=red_lobe, unprotect=unprotect, run_cli=run_cli, FIXTURES=FIXTURES,
        WAVELENGTHS=WAVELENGTHS, S_GRID=S_GRID, INCIDENCE=INCIDENCE)
