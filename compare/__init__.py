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
                                         residual     the chain prepared once for one model's
                                                      geometries (fits, sweeps): ModelResidual
                                         report       report.html, figures, metrics.json
                                         inspect      report of one dataset alone
                                         ratios       opposition and mirror-to-neighbours ratios
                                         sweep        a parameter sweep against a measurement

Library entry points: :func:`compare.comparison.compare_datasets`, and for a model evaluated many
times against one measurement :class:`compare.residual.ModelResidual` (``ModelResidual(measured,
geometries, wavelengths_nm).evaluate(beta[G, L]) -> ResidualFigures``: NRMSE, the residual
vector, dh, ds; the same numbers as ``compare_datasets``); errors a user can fix are
:class:`compare.errors.CompareError` (and :class:`gonio.data.DatasetError` from reading). The
``compare`` command line is :mod:`fabric_optics.cli.compare`.
"""

from gonio.version import VERSION

__version__ = VERSION

__all__ = ["ModelResidual", "ResidualFigures"]


def __getattr__(name: str):
    # lazy: `import compare` (the CLI's start-up) does not load scipy.sparse and the chain
    if name in __all__:
        from . import residual

        return getattr(residual, name)
    raise AttributeError(f"module 'compare' has no attribute {name!r}")
