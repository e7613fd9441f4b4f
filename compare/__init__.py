"""compare: normalise simulations to a measurement, curve errors, HSV colour match, reports.

Data flow (one concept per module)::

    gonio.data.Dataset (measured) ─┐
    gonio.data.Dataset (simulated)─┴─> bands        wavelengths, or the channels of an RGB
                                                      measurement (simulations converted)
                                         align        shared wavelengths and geometries
                                         normalise    k(lambda) = beta_meas(0,0) / C(0,0)
                                         metrics      RMSE, NRMSE, largest deviation
                                         colourmatch  HSV and channel ratios at one geometry
                                         comparison   the chain above + metrics.json document
                                         report       report.html, figures, metrics.json
                                         inspect      report of one dataset alone
                                         cli          `compare report`, `compare check`

Library entry point: :func:`compare.comparison.compare_datasets`; errors a user can fix are
:class:`compare.errors.CompareError` (and :class:`gonio.data.DatasetError` from reading).
"""

__version__ = "0.1.0"
