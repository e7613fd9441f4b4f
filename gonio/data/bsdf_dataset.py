"""A measured dataset as a BRDF callable for the RGL ``.bsdf`` export (``gonio export``).

The export itself is :mod:`gonio.data.bsdf_export`; this module only says how a measurement's
in-plane curves stand for the whole hemisphere, and which datasets cannot be exported.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gonio.data.bsdf_export import BRDF, ExportError

__all__ = ["dataset_brdf", "dataset_nodes"]


def dataset_brdf(dataset: Any) -> tuple[BRDF, dict[str, Any]]:
    """A measured dataset's in-plane curves as a BRDF callable, with the coverage rule stated.

    Rule for the directions a measurement does not cover (``valid`` says nothing about it; the
    returned dict and the export's provenance do): the in-plane curves ``beta(theta_i, s)`` are
    interpolated linearly in ``theta_i`` and ``s``, clamped to the measured ranges of both (nearest
    curve end); a pair with relative azimuth ``dphi`` between the curves is the blend
    ``(1 + cos dphi)/2 beta(theta_i, -theta_o) + (1 - cos dphi)/2 beta(theta_i, +theta_o)``
    (source side to mirror side). Its error against a full-hemisphere truth, in and out of plane:
    docs/explanation/validation.md, "Export to a renderer". Refused: fewer than 2 incidences or
    fewer than 3 observation angles on either side of an incidence, RGB data other than R, G, B,
    relative (raw) units, geometries missing some of the bands.
    """
    from scipy.interpolate import RegularGridInterpolator

    from gonio.data.geometry import signed_angle

    name = getattr(dataset, "source", None) or "dataset"
    if getattr(dataset, "relative", False):
        raise ExportError(f"{name}: relative (raw-unit) values cannot be exported as a BRDF; "
                          "import it with an absolute scale or a white standard first")
    t = dataset.table
    band_col = dataset.band_column
    bands = list(dataset.bands)
    if dataset.is_rgb and bands != ["R", "G", "B"]:
        raise ExportError(f"{name}: channels {','.join(bands)} - an RGB export needs exactly R, G, B")
    s = signed_angle(t["theta_i"].to_numpy(float), t["phi_i"].to_numpy(float),
                     t["theta_o"].to_numpy(float), t["phi_o"].to_numpy(float))
    inplane = t[np.isfinite(s)].assign(s=s[np.isfinite(s)])
    pivot = inplane.pivot_table(index=["theta_i", "s"], columns=band_col, values="beta",
                                aggfunc="mean").reindex(columns=bands)
    if pivot.isna().to_numpy().any():
        raise ExportError(f"{name}: some geometries lack some of the bands "
                          f"({'channels' if dataset.is_rgb else 'wavelengths'} mixed); cannot tabulate")
    incid = np.unique(pivot.index.get_level_values(0))
    if incid.size < 2:
        raise ExportError(f"{name}: {incid.size} in-plane incidence angle(s); an export needs at "
                          "least 2 (the tensor spans 0..90 deg of incidence)")
    grids = []
    for ti in incid:
        sv = pivot.loc[ti].index.to_numpy(float)
        if np.sum(sv < 0) < 3 or np.sum(sv > 0) < 3:
            raise ExportError(f"{name}: incidence {ti:g} deg has fewer than 3 observation angles on "
                              "one side of the normal; cannot interpolate its curve")
        grids.append(sv)
    s_all = np.unique(np.concatenate(grids))
    s_lo, s_hi = max(g.min() for g in grids), min(g.max() for g in grids)
    s_grid = s_all[(s_all >= s_lo) & (s_all <= s_hi)]
    cube = np.stack([np.stack([np.interp(s_grid, pivot.loc[ti].index.to_numpy(float),
                                         pivot.loc[ti][b].to_numpy(float)) for b in bands], -1)
                     for ti in incid])
    interp = RegularGridInterpolator((incid, s_grid), cube, method="linear")

    def beta(wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        ti = np.degrees(np.arccos(np.clip(wi[:, 2], -1, 1)))
        to = np.degrees(np.arccos(np.clip(wo[:, 2], -1, 1)))
        dphi = np.arctan2(wo[:, 1], wo[:, 0]) - np.arctan2(wi[:, 1], wi[:, 0])
        tc = np.clip(ti, incid[0], incid[-1])
        back = interp(np.stack([tc, np.clip(-to, s_grid[0], s_grid[-1])], -1))
        fwd = interp(np.stack([tc, np.clip(to, s_grid[0], s_grid[-1])], -1))
        w = ((1 - np.cos(dphi)) / 2)[:, None]
        return (1 - w) * back + w * fwd

    rule = {"source": "measured dataset (in-plane curves)",
            "incidences_deg": incid.tolist(), "observation_range_deg": [float(s_lo), float(s_hi)],
            "rule": "linear in theta_i and s, clamped to the measured ranges; out-of-plane by the "
                    "(1 +- cos dphi)/2 blend of the source-side and mirror-side curves",
            "extrapolated": "every incidence outside the measured range and every out-of-plane pair"}
    return beta, rule


def dataset_nodes(rule: dict[str, Any], n: int = 16, min_gap_deg: float = 2.0) -> np.ndarray:
    """Incidence nodes for a dataset's export: the measured incidences and ``n`` more.

    The measured incidences themselves (there the file holds the measured curves, not an
    interpolation between nodes) plus ``n`` nodes uniform in ``cos(theta_i)``, dropping those
    within ``min_gap_deg`` of a measured one.
    """
    from gonio.data.bsdf_export import incidence_nodes

    measured = np.asarray(rule["incidences_deg"], float)
    extra = [t for t in incidence_nodes(n) if np.min(np.abs(measured - t)) >= min_gap_deg]
    return np.unique(np.concatenate([measured, extra, [0.0, 90.0]]))
