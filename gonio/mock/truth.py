"""The true radiance coefficient of a mock sample at a plan's geometries, as a dataset.

A virtual sample of the mock (``lambert:RHO``, ``red-cotton`` or a dataset directory; see
:mod:`gonio.mock.samples`) has a known BRDF. Written as a radiance-coefficient dataset at the
geometries and wavelengths of a plan, it is the reference an acquisition on that mock must recover:
``gonio truth red-cotton red-cotton --out truth/`` followed by
``compare report measured/ truth/ --out report/`` checks the whole driver -> dataset -> comparison
pipeline against a known answer. The dataset's kind is ``"simulated"`` (it is a model evaluated at
the geometries, with ``u_beta = 0``) and its ``model`` names the virtual sample.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from gonio.acquisition.plan import Plan
from gonio.data import COLUMNS, Dataset, make_dataset, new_meta

__all__ = ["truth_dataset"]


def truth_dataset(sample_spec: str, plan: Plan) -> Dataset:
    """Evaluate the mock sample ``sample_spec`` at the measurable geometries of ``plan``.

    Raises :class:`gonio.mock.samples.SampleError` for an unknown sample and
    :class:`gonio.data.DatasetError` when a dataset sample does not cover the plan.
    """
    from gonio.mock.samples import make_sample

    sample = make_sample(sample_spec)
    geometries = plan.geometries(measurable_only=True)
    wavelengths = np.asarray(plan.wavelengths_nm, dtype=float)
    g = geometries.loc[geometries.index.repeat(wavelengths.size)].reset_index(drop=True)
    wl = np.tile(wavelengths, len(geometries))
    beta = sample.beta(g["theta_i"].to_numpy(), g["phi_i"].to_numpy(), g["theta_o"].to_numpy(),
                       g["phi_o"].to_numpy(), wl)
    table = pd.DataFrame({"theta_i": g["theta_i"], "phi_i": g["phi_i"], "theta_o": g["theta_o"],
                          "phi_o": g["phi_o"], "wavelength_nm": wl, "beta": beta,
                          "u_beta": 0.0, "n": 1}, columns=list(COLUMNS))
    sample_meta: dict = {"name": f"mock truth ({sample_spec})"}
    measured_incidences = sample.describe().get("measured_incidence_deg")
    if measured_incidences is not None:
        from gonio.data.formats.rgl_bsdf import incidence_meta

        sample_meta["incidences"] = incidence_meta(measured_incidences, geometries["theta_i"].to_numpy(float),
                                                   str(sample_spec).rsplit("/", 1)[-1])
    meta = new_meta("simulated", sample_meta,
                    {"name": "mock virtual sample", "sample": sample.describe()},
                    {"plan": plan.name, "sample_spec": sample_spec})
    return make_dataset(table, meta)
