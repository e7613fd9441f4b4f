r"""The comparison of a model against one measurement, prepared once and evaluated many times.

:func:`compare.comparison.compare_datasets` is the whole chain for any datasets; an inverse
problem (``simulate fit``) or a sweep evaluates the *same* model geometries and wavelengths
against the *same* measurement hundreds of times with only the model's values changing. For
that, :class:`ModelResidual` is built ONCE from the measured dataset and the model's geometries
and wavelengths, and :meth:`ModelResidual.evaluate` takes the model's ``beta[G, L]`` (and
optionally ``u_beta``) and returns the figures ``compare_datasets`` would compute for a dataset
holding those values (:class:`ResidualFigures`): the overall curve error (RMSE, NRMSE), the
per-incidence NRMSE, the residual vector of the fit and the colour differences ``dh``, ``ds``,
``dv`` at the colour geometry::

    from compare import ModelResidual
    res = ModelResidual(measured, geometries, wavelengths_nm)   # geometries: theta_i, phi_i,
    fig = res.evaluate(beta)                                    #   theta_o, phi_o columns
    fig.nrmse, fig.dh, fig.ds, fig.vector(colour_weight=1.0)

How it stays equal to ``compare_datasets`` (tested to 1e-12 relative on the fixtures, an RGB
measurement and a synthetic dataset with gaps, tests/compare/test_residual.py): every step of the
chain is linear in the model's values except the normalisation ratio and the colour, so the
preparation runs the real chain once on a *template* dataset of the model geometries and records
linear maps instead of re-deriving them:

- the bands (:func:`compare.bands.prepare`): for an RGB measurement the spectral model is put
  into the channels by the same conversion matrix ``M`` (channels x wavelengths);
- the alignment (:func:`compare.align.align`) is run once on a view whose values are the row
  numbers, which gives, for every compared point, the model row it matches exactly; points the
  alignment interpolates get their weights by interpolating indicator "spectra" through the
  same public :meth:`gonio.data.Dataset.interpolate` (one per geometry, linear in the values),
  and the wavelength weights of its linear interpolation;
- the normal/normal value ``C(0, 0)`` (:mod:`compare.normalise`) is linear in the values
  (the mean of the normal point, or the intercept of the quadratic: :func:`intercept_weights`),
  selected by the same :func:`normal_selection`;
- the measured side (the measured normal value, the compared measured points, the colour
  geometry and the measured colour) is computed once.

An evaluation is then a few sparse matrix-vector products, ``k = beta_meas(0,0) / C(0,0)``
(:func:`numpy.interp` to the comparison grid, as :func:`compare.normalise.normalisation_factor`),
the curve figures (:func:`compare.metrics.curve_error`'s formulas) and one colour summary of the
scaled model spectrum (:func:`compare.colourmatch` 's rule: ``k_Y``, the same colour function).
No dataset is built, validated, hashed (``same_dataset``) or pivoted per evaluation.

What it does not do: the u-dependent figures of a :class:`compare.comparison.Comparison` (the
normalisation's uncertainty); ``u_beta`` given to :meth:`~ModelResidual.evaluate` is only carried
to :attr:`ResidualFigures.u_simulated`. A model value that is not finite, or a normal value that
is not positive, raises :class:`~compare.errors.CompareError` as ``compare_datasets`` does.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import sparse

from gonio.data import GEOMETRY, Dataset, DatasetError, make_dataset, new_meta
from gonio.data.colour import hue_difference

from .align import align, shared_wavelengths
from .bands import CODES, Bands, conversion_matrix, prepare
from .colourmatch import band_luminance_weights, colour_geometry, colour_of
from .comparison import DYNAMIC_RANGE_MAX, check_values
from .errors import CompareError
from .metrics import angle_key
from .normalise import (
    DEFAULT_WINDOW_DEG,
    check_normal_values,
    estimate_normal_value,
    intercept_weights,
    normal_selection,
)

__all__ = ["ModelResidual", "ResidualFigures"]

_TOL = 1e-9
#: Geometries whose interpolation weights are found per probe dataset (bounds its memory).
_PROBE_BANDS = 128


@dataclass(frozen=True)
class ResidualFigures:
    """The figures of one evaluation (those of :func:`compare.comparison.compare_datasets`).

    Attributes
    ----------
    residual : numpy.ndarray
        ``(k C_j - beta_meas,j) / (mean(beta_meas) sqrt(N))`` over the compared points (in the
        order of the comparison's frame): ``|residual|^2 = NRMSE^2``.
    rmse, nrmse : float
        Overall curve error (:mod:`compare.metrics`).
    nrmse_per_incidence : dict
        ``{angle_key(theta_i): nrmse}`` as ``Comparison.curves[name][key].nrmse``.
    h, s, v, dh, ds, dv : float
        The model's colour at the colour geometry and its differences from the measurement
        (NaN when the measurement has no colour: photometric).
    beta_simulated, u_simulated : numpy.ndarray
        ``k C`` and ``k u_C`` at the compared points (``u_simulated`` NaN without ``u_beta``).
    factor : numpy.ndarray
        ``k`` on the comparison grid.
    has_colour : bool
        False for a photometric (Y-only) measurement: no colour terms.
    """

    residual: np.ndarray
    rmse: float
    nrmse: float
    nrmse_per_incidence: dict
    h: float
    s: float
    v: float
    dh: float
    ds: float
    dv: float
    beta_simulated: np.ndarray
    u_simulated: np.ndarray
    factor: np.ndarray
    has_colour: bool = True
    #: the absolute level: ``k_Y`` at the colour geometry (median ``k`` without colour), as
    #: :meth:`compare.comparison.Comparison.level`; 1 when the model is at the measured level
    level: float = float("nan")

    def vector(self, colour_weight: float = 1.0, level_weight: float = 0.0) -> np.ndarray:
        """The residual vector of ``simulate fit``: ``residual ++ sqrt(colour_weight) [dh, ds]``.

        No colour terms when the measurement has no colour (a photometric one); otherwise
        ``|r|^2 = NRMSE^2 + w (dh^2 + ds^2)``. ``level_weight > 0`` (``simulate fit --absolute``)
        appends ``sqrt(level_weight) ln(level)``, so ``|r|^2`` gains ``w_l (ln k_Y)^2``.

        Parameters
        ----------
        colour_weight : float, default 1
            Weight ``w`` of the squared hue and saturation differences.
        level_weight : float, default 0
            Weight ``w_l`` of the squared log level; 0 leaves the level out.

        Returns
        -------
        numpy.ndarray
            The residual vector (a new array).
        """
        parts = [self.residual]
        if self.has_colour:
            parts.append(math.sqrt(colour_weight) * np.array([self.dh, self.ds]))
        if level_weight > 0:
            lv = self.level if self.level > 0 else float("nan")
            parts.append(np.array([math.sqrt(level_weight) * math.log(lv)]))
        return np.concatenate(parts) if len(parts) > 1 else self.residual.copy()


def _template(geometries: pd.DataFrame, wavelengths: np.ndarray, measured: Dataset, name: str
              ) -> Dataset:
    """The model as a dataset whose ``n`` is its flat index ``g * L + l`` plus one."""
    g = geometries[list(GEOMETRY)].reset_index(drop=True)
    n_g, n_l = len(g), wavelengths.size
    rep = g.loc[g.index.repeat(n_l)].reset_index(drop=True)
    table = pd.DataFrame({c: rep[c].to_numpy(float) for c in GEOMETRY})
    table["wavelength_nm"] = np.tile(wavelengths, n_g)
    table["beta"] = 1.0
    table["u_beta"] = 0.0
    table["n"] = np.arange(1, n_g * n_l + 1, dtype=np.int64)
    sample = {**(measured.meta.get("sample") or {}), "name": name}
    return make_dataset(table, new_meta("simulated", sample, {"name": name}, {}))


def _with_beta(ds: Dataset, beta: np.ndarray) -> Dataset:
    """An in-memory copy of ``ds`` with new values (a view: never validated nor written)."""
    table = ds.table.copy()
    table["beta"] = beta
    table["u_beta"] = 0.0
    return Dataset(table, ds.meta, ds.path)


class ModelResidual:
    """A model's comparison with ``measured``, prepared once (module docstring).

    Parameters
    ----------
    measured : gonio.data.Dataset
        The measurement (spectral or RGB), as given to ``compare_datasets``.
    geometries : pandas.DataFrame
        The model's geometries, columns ``theta_i, phi_i, theta_o, phi_o`` (degrees), one row
        per geometry ``g`` of ``beta[g, l]``.
    wavelengths_nm : array_like
        The model's wavelengths, one per column ``l`` of ``beta[g, l]``.
    window_deg, illuminant :
        As :func:`compare.comparison.compare_datasets`.
    name : str
        The model's name (messages only).

    Raises
    ------
    CompareError, gonio.data.DatasetError
        Whatever ``compare_datasets`` would raise for this measurement and these geometries
        (apart from value-dependent checks, which :meth:`evaluate` makes).
    """

    def __init__(self, measured: Dataset, geometries: pd.DataFrame, wavelengths_nm, *,
                 window_deg: float = DEFAULT_WINDOW_DEG, illuminant: str = "D65",
                 name: str = "model"):
        import colour

        if illuminant not in colour.SDS_ILLUMINANTS:
            raise CompareError(f"unknown illuminant {illuminant!r}; use a key of "
                               "colour.SDS_ILLUMINANTS such as 'D65', 'D50' or 'A'")
        check_values(measured, "measured")
        wl = np.asarray(wavelengths_nm, dtype=float).ravel()
        self.shape = (len(geometries), wl.size)
        self.illuminant = illuminant
        self.name = name
        template = _template(geometries, wl, measured, name)
        self._order = template.table["n"].to_numpy() - 1          # template row -> flat index
        measured_view, views, bands = prepare(measured, [template], [name], illuminant=illuminant)
        self.bands: Bands = bands
        view = views[0]
        self._view_map = self._view_matrix(template, view, bands, illuminant)
        grid = bands.codes() if bands.is_rgb else shared_wavelengths(measured, [template])
        self.grid = grid
        self.window_deg = window_deg
        # the alignment: both sides' values replaced by their row numbers
        n_rows = len(view.table)
        n_meas = len(measured.table)
        meas_index = prepare(_with_beta(measured, np.arange(1.0, n_meas + 1.0)), [template],
                             [name], illuminant=illuminant)[0]
        self._measured_table = measured.table[[c for c in measured.table.columns
                                               if c not in ("beta", "u_beta", "n")]]
        self._meas_view_src = np.rint(meas_index.table["beta"].to_numpy()).astype(int) - 1
        self._meas_view = measured_view
        frame = align(_with_beta(measured_view, np.arange(1.0, len(measured_view.table) + 1.0)),
                      _with_beta(view, np.arange(1.0, n_rows + 1.0)), grid)
        self._align = self._align_matrix(frame, view, n_rows)
        self._meas_rows = np.rint(frame["beta_meas"].to_numpy()).astype(int) - 1  # view rows
        frame["beta_meas"] = measured_view.table["beta"].to_numpy()[self._meas_rows]
        frame["u_meas"] = measured_view.table["u_beta"].to_numpy()[self._meas_rows]
        self.frame = frame[list(GEOMETRY) + ["s", "wavelength_nm", "beta_meas", "u_meas",
                                             "interpolated"]].copy()
        self._row_k = np.searchsorted(grid, frame["wavelength_nm"].to_numpy() - _TOL)
        self._angles = {angle_key(t): np.flatnonzero(frame["theta_i"].to_numpy() == t)
                        for t in np.unique(frame["theta_i"].to_numpy())}
        # the model's normal/normal value: structure checked by the real estimate, then weights; like
        # for like with the measurement (compare.normalise.estimate_normal_value, use_exact)
        self._use_exact = estimate_normal_value(measured_view, window_deg, bands.label).how == "measured"
        estimate_normal_value(_with_beta(view, np.ones(n_rows)), window_deg, bands.label, use_exact=self._use_exact)
        self._view_wl = view.wavelengths_nm
        self._normal, self._normal_exact = self._normal_matrix(view, window_deg, n_rows)
        self._view_ds = view
        # the colour: geometry, rows and the measured colour, once
        self.has_colour = bands.has_colour
        if self.has_colour:
            geometry = colour_geometry({name: frame})
            self.colour_geometry = geometry
            mask = np.ones(len(frame), dtype=bool)
            for c in GEOMETRY:
                mask &= np.abs(frame[c].to_numpy() - geometry[c]) < 1e-6
            rows = frame[mask].sort_values("wavelength_nm")
            self._c_rows = rows.index.to_numpy()
            self._c_wl = rows["wavelength_nm"].to_numpy()
            self._w = band_luminance_weights(bands, self._c_wl, illuminant)
        self._measured_side(measured_view)

    def _measured_side(self, measured_view: Dataset) -> None:
        """Everything that depends on the measured values (the measured view given)."""
        measured_normal = estimate_normal_value(measured_view, self.window_deg, self.bands.label)
        self._m = measured_normal.at(self.grid)[0]
        self._meas = measured_view.table["beta"].to_numpy(float)[self._meas_rows]
        self._mean = float(np.mean(self._meas))
        if self.has_colour:
            self.measured_colour = colour_of(self._c_wl, self._meas[self._c_rows], self.illuminant,
                                             "the measured dataset", self.bands)

    def with_measured(self, measured: Dataset) -> ModelResidual:
        """A copy against ``measured``; only the measured side is recomputed.

        ``measured`` has the SAME rows as the dataset prepared (new values: e.g. a noise draw of
        the measurement).

        Parameters
        ----------
        measured : Dataset
            The measurement with the prepared rows and new values.

        Returns
        -------
        ModelResidual
            The copy; the original is unchanged.

        Raises
        ------
        CompareError
            ``measured`` has other rows (prepare a new :class:`ModelResidual`).
        """
        cols = list(self._measured_table.columns)
        if len(measured.table) != len(self._measured_table) or not measured.table[cols].equals(
                self._measured_table):
            raise CompareError(f"measured dataset '{measured.name}' does not have the rows of the "
                               "prepared one; prepare a new ModelResidual")
        out = copy.copy(self)
        view = self._meas_view
        table = view.table.copy()
        table["beta"] = measured.table["beta"].to_numpy(float)[self._meas_view_src]
        table["u_beta"] = measured.table["u_beta"].to_numpy(float)[self._meas_view_src]
        out._meas_view = Dataset(table, view.meta, view.path)
        out._measured_side(out._meas_view)
        return out

    # -- preparation --------------------------------------------------------------------------

    def _view_matrix(self, template: Dataset, view: Dataset, bands: Bands, illuminant: str):
        """Sparse map from the model's values in template-row order to the compared view's rows."""
        n_t = len(template.table)
        if not bands.is_rgb:
            return sparse.identity(n_t, format="csr")
        # RGB: each geometry's spectrum times M (channels kept by the comparison)
        wl = template.wavelengths_nm
        n_l = wl.size
        channels = [bands.label(c) for c in bands.codes()]
        m = conversion_matrix(wl, channels, bands.colour_space or "linear sRGB", illuminant)
        t = template.table
        key = t[list(GEOMETRY)].round(6)
        g_index = key.drop_duplicates().reset_index(drop=True).reset_index().merge(key, how="right")
        g_of_row = g_index["index"].to_numpy()           # template row -> geometry number
        first_row = np.flatnonzero(np.r_[True, np.diff(g_of_row) != 0])
        vt = view.table
        vkey = vt[list(GEOMETRY)].round(6).merge(
            key.iloc[first_row].reset_index(drop=True).reset_index(), how="left")
        if vkey["index"].isna().any():
            raise CompareError("internal: a converted model geometry was not found")
        g_view = vkey["index"].to_numpy(int)
        code_index = {CODES[c]: j for j, c in enumerate(channels)}
        c_view = np.array([code_index[float(x)] for x in vt["wavelength_nm"].to_numpy()])
        rows = np.repeat(np.arange(len(vt)), n_l)
        cols = (first_row[g_view][:, None] + np.arange(n_l)[None, :]).ravel()
        vals = m[c_view].ravel()
        return sparse.csr_matrix((vals, (rows, cols)), shape=(len(vt), n_t))

    def _align_matrix(self, frame: pd.DataFrame, view: Dataset, n_rows: int):
        """Sparse map from the view's rows to the frame's ``beta_sim_raw``."""
        interpolated = frame["interpolated"].to_numpy(bool)
        exact_rows = np.flatnonzero(~interpolated)
        exact_cols = np.rint(frame["beta_sim_raw"].to_numpy()[exact_rows]).astype(int) - 1
        rows = [exact_rows]
        cols = [exact_cols]
        vals = [np.ones(exact_rows.size)]
        if interpolated.any():
            vt = view.table
            geo = vt[list(GEOMETRY)].drop_duplicates().reset_index(drop=True)
            key = vt[list(GEOMETRY)].round(6).reset_index()
            geo_key = geo.round(6).reset_index().rename(columns={"index": "g"})
            row_g = key.merge(geo_key, how="left").sort_values("index")["g"].to_numpy()
            bands_v = view.wavelengths_nm
            row_l = np.searchsorted(bands_v, vt["wavelength_nm"].to_numpy() - _TOL)
            flat_to_row = np.full((len(geo), bands_v.size), -1)
            flat_to_row[row_g, row_l] = np.arange(len(vt))
            # indicator spectra: "band" j of the probe is 1 at geometry j, in chunks of
            # _PROBE_BANDS bands (memory n_g x _PROBE_BANDS, not n_g^2)
            n_g = len(geo)
            groups = list(frame[interpolated].groupby(list(GEOMETRY), sort=False))
            weights = np.zeros((len(groups), n_g))
            for j0 in range(0, n_g, _PROBE_BANDS):
                j1 = min(j0 + _PROBE_BANDS, n_g)
                band = np.arange(j0, j1, dtype=float)
                probe_t = geo.loc[geo.index.repeat(j1 - j0)].reset_index(drop=True)
                probe_t["wavelength_nm"] = np.tile(band, n_g)
                probe_t["beta"] = (np.repeat(np.arange(n_g), j1 - j0)
                                   == np.tile(np.arange(j0, j1), n_g)).astype(float)
                probe_t["u_beta"] = 0.0
                probe_t["n"] = 1
                probe = Dataset(probe_t, dict(view.meta), view.path)
                for q, (_, grp) in enumerate(groups):
                    first = grp.iloc[0]
                    a, b, c, d = (np.full(j1 - j0, float(first[col])) for col in GEOMETRY)
                    try:
                        weights[q, j0:j1] = probe.interpolate(a, b, c, d, band)[0]
                    except DatasetError as exc:  # align interpolated it: so must the probe
                        raise CompareError(f"internal: geometry weights not found ({exc})") from None
            for q, (_, grp) in enumerate(groups):
                w_geo = weights[q]
                nz = np.flatnonzero(w_geo != 0.0)
                for r, at in zip(grp.index.to_numpy(), grp["wavelength_nm"].to_numpy(float), strict=True):
                    j = int(np.clip(np.searchsorted(bands_v, at) - 1, 0, max(bands_v.size - 2, 0)))
                    if bands_v.size > 1:
                        f = float(np.clip((at - bands_v[j]) / (bands_v[j + 1] - bands_v[j]), 0, 1))
                        parts = [(j, 1.0 - f), (j + 1, f)]
                    else:
                        parts = [(0, 1.0)]
                    for jj, fw in parts:
                        rows.append(np.full(nz.size, r))
                        cols.append(flat_to_row[nz, jj])
                        vals.append(fw * w_geo[nz])
        r_all, c_all, v_all = (np.concatenate(x) for x in (rows, cols, vals))
        keep = v_all != 0.0
        return sparse.csr_matrix((v_all[keep], (r_all[keep], c_all[keep])),
                                 shape=(len(frame), n_rows))

    def _normal_matrix(self, view: Dataset, window_deg: float, n_rows: int):
        """Sparse map from the view's rows to ``C(0, 0)`` on the view's bands."""
        indexed = _with_beta(view, np.arange(1.0, n_rows + 1.0))
        rows = indexed.in_plane(theta_i=0.0)
        wl_rows = rows["wavelength_nm"].to_numpy()
        s_all = rows["s"].to_numpy()
        src = np.rint(rows["beta"].to_numpy()).astype(int) - 1
        r_out, c_out, v_out = [], [], []
        exact_all = np.zeros(self._view_wl.size, dtype=bool)
        for k, wl in enumerate(self._view_wl):
            sel = np.abs(wl_rows - wl) < 1e-9
            s = s_all[sel]
            exact, mask = normal_selection(view, s, wl, window_deg, self.bands.label, self._use_exact)
            weights = (np.full(int(mask.sum()), 1.0 / mask.sum()) if exact
                       else intercept_weights(s[mask]))
            exact_all[k] = exact
            r_out.append(np.full(weights.size, k))
            c_out.append(src[sel][mask])
            v_out.append(weights)
        matrix = sparse.csr_matrix((np.concatenate(v_out), (np.concatenate(r_out),
                                                            np.concatenate(c_out))),
                                   shape=(self._view_wl.size, n_rows))
        return matrix, exact_all

    # -- evaluation ---------------------------------------------------------------------------

    def evaluate(self, beta, u_beta=None) -> ResidualFigures:
        """The comparison figures of the model values ``beta[G, L]`` (module docstring).

        Parameters
        ----------
        beta : array_like, shape (G, L)
            The model's radiance coefficients at the prepared geometries (rows) and wavelengths
            (columns).
        u_beta : array_like, shape (G, L), optional
            Their standard uncertainties (Monte Carlo); None: zero.

        Returns
        -------
        ResidualFigures
            NRMSE, the residual vector, the colour differences and the level, as
            :func:`compare.comparison.compare_datasets` would give them.

        Raises
        ------
        CompareError
            ``beta`` of the wrong shape or not finite, or a model normal value that is not a
            positive finite number (as ``compare_datasets``).
        """
        b = np.asarray(beta, dtype=float)
        if b.shape != self.shape:
            raise CompareError(f"model values of shape {b.shape}, expected {self.shape} "
                               "(geometries x wavelengths)")
        if not np.all(np.isfinite(b)):
            raise CompareError(f"model '{self.name}': values are not all finite numbers")
        size = np.abs(b)
        nonzero = size[size > 0]
        if nonzero.size and size.max() > DYNAMIC_RANGE_MAX * float(np.median(nonzero)):
            raise CompareError(f"model '{self.name}': a value {b.flat[int(np.argmax(size))]:g} "
                               f"is more than {DYNAMIC_RANGE_MAX:g} times the median |beta| "
                               "(compare.comparison.check_values)")
        values = self._view_map @ b.ravel()[self._order]
        normal = self._normal @ values
        check_normal_values(self._view_ds, self._view_wl, normal, self._normal_exact,
                            self.bands.label)
        c = np.interp(self.grid, self._view_wl, normal)
        k = self._m / c
        raw = self._align @ values
        k_rows = k[self._row_k]
        sim = k_rows * raw
        if u_beta is not None:
            u = np.broadcast_to(np.asarray(u_beta, dtype=float), self.shape)
            u_sim = k_rows * (self._align @ np.sqrt(self._view_map.power(2)
                                                    @ (u.ravel()[self._order] ** 2)))
        else:
            u_sim = np.full(sim.size, np.nan)
        d = sim - self._meas
        rmse = float(np.sqrt(np.mean(d * d)))
        nrmse = rmse / self._mean if self._mean > 0 else float("nan")
        per_angle = {}
        for key, idx in self._angles.items():
            dd = d[idx]
            mean = float(np.mean(self._meas[idx]))
            r = float(np.sqrt(np.mean(dd * dd)))
            per_angle[key] = r / mean if mean > 0 else float("nan")
        h = s = v = dh = ds = dv = float("nan")
        level = float(np.median(k))
        if self.has_colour:
            scale = float(self._w @ self._m) / float(self._w @ c)
            level = scale
            col = colour_of(self._c_wl, raw[self._c_rows] * scale, self.illuminant,
                          f"simulated dataset '{self.name}' (scaled by k_Y {scale:.3g})",
                          self.bands)
            mc = self.measured_colour
            h, s, v = col.h, col.s, col.v
            dh, ds, dv = float(hue_difference(mc.h, col.h)), col.s - mc.s, col.v - mc.v
        return ResidualFigures(residual=d / (self._mean * math.sqrt(d.size)), rmse=rmse,
                               nrmse=nrmse, nrmse_per_incidence=per_angle, h=h, s=s, v=v, dh=dh,
                               ds=ds, dv=dv, beta_simulated=sim, u_simulated=u_sim, factor=k,
                               has_colour=self.has_colour, level=level)
