"""Screen a flattened fibre cross-section against the felt's forward rise, in two dimensions.

    python docs/scripts/fibre_section_screen.py [--config green-felt-mc] [--rays 200000] [--seed 0]
        [--json OUT.json]

The felt's forward rise ``S(70)/S(30)`` (the fibre's intensity 70 deg from the felt's normal on the mirror's
side over that at 30 deg) is too small in the model at 0-50 deg incidence (docs/notes/felt-structure.md,
sections 10 and 11). A fibre whose section is an ellipse lying flat in the felt's plane might raise it. The
fibre Monte Carlo of the toolkit traces round fibres only, so this screen traces the section in the plane
normal to the fibre's axis (the fibre lying across the plane of incidence), round and elliptical, with
everything else the config's fibre: the host's index, the dye's absorption and the scatterers' coefficient and
asymmetry at each band, the surface's reflection and transmission slopes. An ellipse keeps the round fibre's
area (semi-axes ``r sqrt(k)`` along the felt's plane and ``r / sqrt(k)`` along its normal, aspect ``k``).

The ray optics, all orders: a parallel beam at ``theta_i`` from the felt's normal falls on the section at a
uniformly drawn offset across its projected width; at each interface the Fresnel reflectance (unpolarised,
exact) decides between reflection and refraction (total internal reflection included); a rough interface
tilts the local normal by an angle whose tangent is normal with standard deviation ``slope / sqrt(2)`` (one
component of an isotropic surface's slope; the reflection's slope for a reflection, the transmission's for a
refraction, as the fibre model splits them); inside, the weight falls as ``exp(-mu_a l)`` along each length and
the scatterers deflect a ray after an exponential free path of mean ``1 / mu_s`` by the wrapped Cauchy
distribution of mean cosine ``g`` (the two-dimensional Henyey-Greenstein). Exiting weights are binned by their
angle from the felt's normal; ``S(theta)`` is the weight within 5 deg of ``theta`` on the mirror's side. Each
ratio's standard error comes from the spread over ten batches of the rays.

Orientations: ``flat`` (the major axis in the felt's plane) and ``random`` (the section's rotation uniform).
The screen is two-dimensional (a fibre across the plane of incidence, no axial tilt, no neighbours), so its
ratios are not the felt's: what it tells is the direction and size of the change from round to flat. A
section is worth building into the fibre Monte Carlo only if it raises at least three of the four forward
rises (0, 27.76, 40.03, 50.16 deg) the file asks for.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

#: the felt file's measured incidences (deg) at which the forward rise is short in the model
INCIDENCES_DEG = (0.0, 27.755, 40.026, 50.16)
#: the view angles (deg from the felt's normal, mirror side) of the forward rise, and the bins' half-width
VIEWS_DEG = (30.0, 70.0)
HALF_BIN_DEG = 5.0
ASPECTS = (1.0, 1.3, 1.6, 2.0)
ORIENTATIONS = ("flat", "random")
BANDS_NM = (550.0, 650.0)
MAX_EVENTS = 200
BATCHES = 10


def fresnel_unpolarised(cos_i: np.ndarray, n_ratio: np.ndarray | float) -> np.ndarray:
    """The unpolarised Fresnel reflectance at incidence cosines ``cos_i``, 1 beyond the critical angle.

    Parameters
    ----------
    cos_i : numpy.ndarray
        Incidence cosines (> 0; clipped to [0, 1]).
    n_ratio : numpy.ndarray or float
        Relative index of the medium entered, ``n_transmitted / n_incident`` (per ray, or one for all).

    Returns
    -------
    numpy.ndarray
        The mean of the s and p reflectances, per ray.
    """
    cos_i = np.clip(cos_i, 0.0, 1.0)
    sin_t2 = (1.0 - cos_i**2) / np.asarray(n_ratio) ** 2
    tir = sin_t2 >= 1.0
    cos_t = np.sqrt(np.clip(1.0 - sin_t2, 0.0, 1.0))
    rs = (cos_i - n_ratio * cos_t) / (cos_i + n_ratio * cos_t)
    rp = (n_ratio * cos_i - cos_t) / (n_ratio * cos_i + cos_t)
    return np.where(tir, 1.0, 0.5 * (rs**2 + rp**2))


def _rot(vx: np.ndarray, vy: np.ndarray, c: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vectors ``(vx, vy)`` rotated by the angles whose cosines and sines are ``c`` and ``s``."""
    return c * vx - s * vy, s * vx + c * vy


class Section:
    """An ellipse rotated per ray: intersections and normals in the felt's frame.

    Parameters
    ----------
    a : float
        Semi-axis along the ellipse's own x (um).
    b : float
        Semi-axis along its own y (um).
    phi : numpy.ndarray
        The ellipse's rotation per ray (radians, from the felt's plane); the ellipse is centred at the origin.
    """

    def __init__(self, a: float, b: float, phi: np.ndarray):
        self.a, self.b = a, b
        self.c, self.s = np.cos(phi), np.sin(phi)

    def to_local(self, x, y, idx):
        """Vectors of the felt's frame in the section's own frame, for the rays ``idx``.

        Parameters
        ----------
        x, y : numpy.ndarray
            The vectors' components in the felt's frame.
        idx : numpy.ndarray
            The rays (indices into the per-ray rotation).

        Returns
        -------
        tuple of numpy.ndarray
            The components along the section's own axes.
        """
        return _rot(x, y, self.c[idx], -self.s[idx])

    def to_felt(self, x, y, idx):
        """Vectors of the section's own frame in the felt's frame, for the rays ``idx``.

        Parameters
        ----------
        x, y : numpy.ndarray
            The vectors' components along the section's own axes.
        idx : numpy.ndarray
            The rays (indices into the per-ray rotation).

        Returns
        -------
        tuple of numpy.ndarray
            The components in the felt's frame.
        """
        return _rot(x, y, self.c[idx], self.s[idx])

    def exit_distance(self, px, py, dx, dy, idx):
        """The distance along (dx, dy) from an inside point to the boundary (the larger root).

        Parameters
        ----------
        px, py : numpy.ndarray
            The points, inside the section (felt's frame).
        dx, dy : numpy.ndarray
            The unit directions.
        idx : numpy.ndarray
            The rays the points belong to.

        Returns
        -------
        numpy.ndarray
            The distances (0 where rounding puts a point outside behind the boundary).
        """
        lx, ly = self.to_local(px, py, idx)
        ux, uy = self.to_local(dx, dy, idx)
        qa = (ux / self.a) ** 2 + (uy / self.b) ** 2
        qb = 2 * (lx * ux / self.a**2 + ly * uy / self.b**2)
        qc = (lx / self.a) ** 2 + (ly / self.b) ** 2 - 1.0
        disc = np.sqrt(np.clip(qb**2 - 4 * qa * qc, 0.0, None))
        return np.maximum((-qb + disc) / (2 * qa), 0.0)

    def entry_distance(self, px, py, dx, dy, idx):
        """The distance along (dx, dy) from an outside point to the boundary (the smaller root; NaN on a miss).

        Parameters
        ----------
        px, py : numpy.ndarray
            The points, outside the section (felt's frame).
        dx, dy : numpy.ndarray
            The unit directions.
        idx : numpy.ndarray
            The rays the points belong to.

        Returns
        -------
        numpy.ndarray
            The distances, NaN for a ray that misses the section.
        """
        lx, ly = self.to_local(px, py, idx)
        ux, uy = self.to_local(dx, dy, idx)
        qa = (ux / self.a) ** 2 + (uy / self.b) ** 2
        qb = 2 * (lx * ux / self.a**2 + ly * uy / self.b**2)
        qc = (lx / self.a) ** 2 + (ly / self.b) ** 2 - 1.0
        disc = qb**2 - 4 * qa * qc
        return np.where(disc >= 0, (-qb - np.sqrt(np.clip(disc, 0, None))) / (2 * qa), np.nan)

    def normal(self, px, py, idx):
        """The outward unit normal at boundary points.

        Parameters
        ----------
        px, py : numpy.ndarray
            Points on the boundary (felt's frame).
        idx : numpy.ndarray
            The rays the points belong to.

        Returns
        -------
        tuple of numpy.ndarray
            The normal's components in the felt's frame.
        """
        lx, ly = self.to_local(px, py, idx)
        nx, ny = lx / self.a**2, ly / self.b**2
        norm = np.hypot(nx, ny)
        return self.to_felt(nx / norm, ny / norm, idx)

    def half_width(self, px: float, py: float) -> np.ndarray:
        """Half the section's width across the unit direction (px, py), per ray.

        Parameters
        ----------
        px, py : float
            The unit direction across which the width is taken (felt's frame).

        Returns
        -------
        numpy.ndarray
            The half-width for each ray's rotation (um).
        """
        lx, ly = _rot(px, py, self.c, -self.s)
        return np.sqrt((self.a * lx) ** 2 + (self.b * ly) ** 2)


def _tilt(nx, ny, slope_sigma, rng):
    """The normal tilted by an angle whose tangent is N(0, slope_sigma)."""
    if slope_sigma <= 0:
        return nx, ny
    t = np.arctan(rng.normal(0.0, slope_sigma, size=nx.shape))
    return _rot(nx, ny, np.cos(t), np.sin(t))


def trace(aspect: float, orientation: str, theta_i_deg: float, *, radius_um: float, n_host: float, mu_a: float,
          mu_s: float, g: float, reflect_slope: float, transmit_slope: float, rays: int,
          rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Trace ``rays`` rays of a beam at ``theta_i_deg`` through one section, all orders (module docstring).

    Parameters
    ----------
    aspect : float
        The ellipse's aspect ``k`` (1: round); its area is the round fibre's.
    orientation : {"flat", "random"}
        ``flat``: the major axis in the felt's plane; ``random``: the rotation uniform per ray.
    theta_i_deg : float
        The beam's angle from the felt's normal (deg).
    radius_um : float
        The round fibre's radius (um).
    n_host : float
        The fibre's refractive index (in air).
    mu_a : float
        The dye's absorption coefficient (1/um).
    mu_s : float
        The scatterers' scattering coefficient (1/um; 0: no scattering).
    g : float
        The scatterers' mean cosine (of the wrapped Cauchy distribution).
    reflect_slope : float
        The surface's RMS slope for reflections.
    transmit_slope : float
        The surface's RMS slope for refractions.
    rays : int
        Number of rays, split into :data:`BATCHES` batches for the standard errors.
    rng : numpy.random.Generator
        The draws' source.

    Returns
    -------
    dict of numpy.ndarray
        Per exit: ``angle`` (deg from the felt's normal, positive on the mirror's side, beyond 90
        below the felt's plane), ``weight`` and ``batch``. A ray still inside after :data:`MAX_EVENTS`
        events is dropped.
    """
    a, b = radius_um * np.sqrt(aspect), radius_um / np.sqrt(aspect)
    phi = np.zeros(rays) if orientation == "flat" else rng.uniform(0.0, np.pi, rays)
    sec = Section(a, b, phi)
    ti = np.radians(theta_i_deg)
    dx, dy = np.full(rays, np.sin(ti)), np.full(rays, -np.cos(ti))
    qx, qy = np.cos(ti), np.sin(ti)                          # across the beam
    h = sec.half_width(qx, qy)
    off = rng.uniform(-1.0, 1.0, rays) * h
    far = 4 * radius_um * max(aspect, 1 / aspect)
    px, py = off * qx - far * dx, off * qy - far * dy
    idx = np.arange(rays)
    t = sec.entry_distance(px, py, dx, dy, idx)
    t = np.where(np.isnan(t), 0.0, t)                        # every offset within the half-width hits
    px, py = px + t * dx, py + t * dy
    w = h / h.mean()                                          # a ray carries the section's width it stands for
    inside = np.zeros(rays, bool)
    out_angle, out_w, out_ray = [], [], []
    sr, st = reflect_slope / np.sqrt(2), transmit_slope / np.sqrt(2)
    alive = np.ones(rays, bool)
    for _ in range(MAX_EVENTS):
        live = np.flatnonzero(alive)
        if live.size == 0:
            break
        # inside: move to a scattering or to the boundary
        ins = live[inside[live]]
        if ins.size:
            tb = sec.exit_distance(px[ins], py[ins], dx[ins], dy[ins], ins)
            s = rng.exponential(1.0 / mu_s, ins.size) if mu_s > 0 else np.full(ins.size, np.inf)
            step = np.minimum(s, tb)
            px[ins] += step * dx[ins]; py[ins] += step * dy[ins]
            w[ins] *= np.exp(-mu_a * step)
            sc = ins[s < tb]
            if sc.size:
                rho = (1 - g) / (1 + g)
                dth = 2 * np.arctan(rho * np.tan(np.pi * (rng.uniform(size=sc.size) - 0.5)))
                dx[sc], dy[sc] = _rot(dx[sc], dy[sc], np.cos(dth), np.sin(dth))
            at = ins[s >= tb]
        else:
            at = ins
        # interface events: rays outside (on the boundary, arriving) and rays inside at the boundary
        ev = np.concatenate([live[~inside[live]], at])
        if ev.size == 0:
            continue
        nx, ny = sec.normal(px[ev], py[ev], ev)
        from_in = inside[ev]
        sign = np.where(from_in, -1.0, 1.0)                  # the normal on the incident side
        n_ratio = np.where(from_in, 1.0 / n_host, n_host)
        mtx, mty = _tilt(nx, ny, st, rng)
        cos_i = -(dx[ev] * mtx + dy[ev] * mty) * sign
        bad = cos_i <= 1e-9
        mtx, mty = np.where(bad, nx, mtx), np.where(bad, ny, mty)
        cos_i = np.where(bad, -(dx[ev] * nx + dy[ev] * ny) * sign, cos_i)
        refl = rng.uniform(size=ev.size) < fresnel_unpolarised(cos_i, n_ratio)
        # refraction through the transmission's micro-normal
        mnx, mny = mtx * sign, mty * sign                    # towards the incident side
        eta = 1.0 / n_ratio
        k = 1 - eta**2 * (1 - cos_i**2)
        tx = eta * dx[ev] + (eta * cos_i - np.sqrt(np.clip(k, 0, None))) * mnx
        ty = eta * dy[ev] + (eta * cos_i - np.sqrt(np.clip(k, 0, None))) * mny
        # reflection about the reflection's micro-normal (the macro normal if it would cross the surface)
        rx0, ry0 = _tilt(nx, ny, sr, rng)
        rnx, rny = rx0 * sign, ry0 * sign
        c = dx[ev] * rnx + dy[ev] * rny
        rx, ry = dx[ev] - 2 * c * rnx, dy[ev] - 2 * c * rny
        wrong = (rx * nx + ry * ny) * sign <= 0
        c0 = dx[ev] * nx * sign + dy[ev] * ny * sign
        rx = np.where(wrong, dx[ev] - 2 * c0 * nx * sign, rx)
        ry = np.where(wrong, dy[ev] - 2 * c0 * ny * sign, ry)
        ndx, ndy = np.where(refl, rx, tx), np.where(refl, ry, ty)
        norm = np.hypot(ndx, ndy)
        dx[ev], dy[ev] = ndx / norm, ndy / norm
        now_in = np.where(refl, from_in, ~from_in)
        inside[ev] = now_in
        leave = ev[~now_in]
        if leave.size:
            out_angle.append(np.degrees(np.arctan2(dx[leave], dy[leave])))
            out_w.append(w[leave].copy()); out_ray.append(leave.copy())
            alive[leave] = False
        # nudge off the boundary along the new direction
        px[ev] += 1e-9 * radius_um * dx[ev]; py[ev] += 1e-9 * radius_um * dy[ev]
    return {"angle": np.concatenate(out_angle), "weight": np.concatenate(out_w),
            "batch": np.concatenate(out_ray) * BATCHES // rays}


def forward_rise(result: dict[str, np.ndarray]) -> tuple[float, float]:
    """``S(70)/S(30)`` on the mirror's side and its standard error over the batches.

    Parameters
    ----------
    result : dict of numpy.ndarray
        A :func:`trace` result.

    Returns
    -------
    tuple of (float, float)
        The ratio of all rays (NaN when no weight falls near 30 deg), and the standard error of the
        batches' ratios (NaN from fewer than two finite ones).
    """
    ang, w, batch = result["angle"], result["weight"], result["batch"]

    def ratio(sel):
        """``S(70)/S(30)`` of the exits selected by ``sel`` (NaN when none is near 30 deg)."""
        s = [w[sel & (np.abs(ang - v) <= HALF_BIN_DEG)].sum() for v in VIEWS_DEG]
        return s[1] / s[0] if s[0] > 0 else np.nan

    whole = ratio(np.ones(ang.size, bool))
    per = np.array([ratio(batch == k) for k in range(BATCHES)])
    per = per[np.isfinite(per)]
    se = float(per.std(ddof=1) / np.sqrt(per.size)) if per.size > 1 else float("nan")
    return float(whole), se


def fibre_properties(config: str, bands_nm: tuple[float, ...]) -> dict[str, Any]:
    """The config's fibre at ``bands_nm``: radius, host index, mu_s, mu_a, g per band, the surface's slopes.

    Parameters
    ----------
    config : str
        A config preset's name or a TOML path.
    bands_nm : tuple of float
        The bands (nm).

    Returns
    -------
    dict
        The config's name and the fibre's properties, as JSON numbers and lists.
    """
    from simulate.config import load_config

    cfg = load_config(config)
    wl = np.asarray(bands_nm, float)
    fib = cfg.fiber(wl)
    mu_s, mu_a, g = fib.medium.coefficients(wl)
    return {"config": config, "radius_um": float(fib.radius_um), "n_host": float(fib.n_host),
            "reflect_slope": float(fib.roughness), "transmit_slope": float(fib.transmission_roughness),
            "bands_nm": [float(x) for x in wl], "mu_s_per_um": [float(x) for x in mu_s],
            "mu_a_per_um": [float(x) for x in mu_a], "g": [float(x) for x in g]}


def screen(fibre: dict[str, Any], *, rays: int, seed: int, aspects=ASPECTS, orientations=ORIENTATIONS,
           incidences=INCIDENCES_DEG) -> list[dict[str, Any]]:
    """Every (aspect, orientation, band, incidence): the forward rise, its error and the change from round.

    The change is from the round section of the same orientation, band and incidence, with its
    standard error from both rises'.

    Parameters
    ----------
    fibre : dict
        A :func:`fibre_properties` result.
    rays : int
        Rays per section and incidence.
    seed : int
        The seed; each trace draws from its own generator, keyed by the seed and the trace's indices.
    aspects : tuple of float
        The aspects to trace (1.0 among them: the round section the changes are from).
    orientations : tuple of str
        Of :data:`ORIENTATIONS`.
    incidences : tuple of float
        The beam's angles (deg).

    Returns
    -------
    list of dict
        One row per trace: the band, orientation, aspect and incidence, the rise and its standard
        error, the albedo, and the change from round and its standard error (NaN when the round
        section's rise is 0).
    """
    rows = []
    for bi, band in enumerate(fibre["bands_nm"]):
        for orient in orientations:
            for aspect in aspects:
                for th in incidences:
                    rng = np.random.default_rng([seed, bi, ORIENTATIONS.index(orient), int(aspect * 100), int(th * 1000)])
                    res = trace(aspect, orient, th, radius_um=fibre["radius_um"], n_host=fibre["n_host"],
                                mu_a=fibre["mu_a_per_um"][bi], mu_s=fibre["mu_s_per_um"][bi], g=fibre["g"][bi],
                                reflect_slope=fibre["reflect_slope"], transmit_slope=fibre["transmit_slope"],
                                rays=rays, rng=rng)
                    r, se = forward_rise(res)
                    rows.append({"band_nm": band, "orientation": orient, "aspect": aspect, "theta_i_deg": th,
                                 "rise": r, "rise_se": se, "albedo": float(res["weight"].sum() / rays)})
    for row in rows:
        base = next(x for x in rows if x["aspect"] == 1.0 and x["orientation"] == row["orientation"]
                    and x["band_nm"] == row["band_nm"] and x["theta_i_deg"] == row["theta_i_deg"])
        if row is base:
            row["change"], row["change_se"] = 0.0, 0.0
        elif base["rise"] > 0:
            row["change"] = row["rise"] / base["rise"] - 1.0
            row["change_se"] = float(np.hypot(row["rise_se"] / base["rise"],
                                              base["rise_se"] * row["rise"] / base["rise"] ** 2))
        else:                                                 # too few rays in the round section's views
            row["change"], row["change_se"] = float("nan"), float("nan")
    return rows


def main(argv: list[str] | None = None) -> int:
    """Trace the screen, print a table of the forward rises and write the rows as JSON.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (``--config``, ``--rays``, ``--seed``, ``--json``); ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0, or 2 when ``--rays`` is too small for the batches (one line says so).
    """
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="green-felt-mc", help="the fibre's config (default green-felt-mc)")
    ap.add_argument("--rays", type=int, default=200_000, help="rays per section and incidence (default 200000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, help="write the rows and the fibre's properties here")
    args = ap.parse_args(argv)
    if args.rays < 10 * BATCHES:
        print(f"fibre_section_screen: --rays must be at least {10 * BATCHES}", file=sys.stderr)
        return 2
    fibre = fibre_properties(args.config, BANDS_NM)
    rows = screen(fibre, rays=args.rays, seed=args.seed)
    print("band  orientation aspect  " + "  ".join(f"rise {t:5.2f}" for t in INCIDENCES_DEG) + "   raised")
    for band in BANDS_NM:
        for orient in ORIENTATIONS:
            for aspect in ASPECTS:
                sel = [r for r in rows if r["band_nm"] == band and r["orientation"] == orient and r["aspect"] == aspect]
                raised = sum(r["change"] > 2 * r["change_se"] for r in sel) if aspect != 1.0 else "-"
                print(f"{band:4.0f}  {orient:11s} {aspect:4.1f}  "
                      + "  ".join(f"{r['rise']:5.3f}±{r['rise_se']:.3f}" for r in sel) + f"   {raised}")
    if args.json:
        args.json.write_text(json.dumps({"fibre": fibre, "rays": args.rays, "seed": args.seed,
                                         "views_deg": VIEWS_DEG, "half_bin_deg": HALF_BIN_DEG, "rows": rows},
                                        indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
