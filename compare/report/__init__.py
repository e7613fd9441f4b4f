"""The comparison report: ``report.html`` (one self-contained file), ``figures/*.png``,
``metrics.json`` -- a list of sections.

One concept per module:

==============  ===============================================================================
``curves``      the data drawn: in-plane rows, luminance and single-wavelength curves, gaps
``figures``     the matplotlib figures and :func:`save_figure`
``prose``       words: dataset summaries, number formatting, banners
``page``        ``report.html`` assembled from :class:`Section` s
``outdir``      the output-folder policy (:func:`prepare_out_dir`)
``build``       :func:`write_report`: the orchestration
``samples``     sections "What was measured" (the mock's sample, a real file's source) and the
                seed sample's published-colour check
``fits``        section "Fitted parameters" (``simulate fit``'s ``fit.json``)
``shape``       section "Shape ratios": opposition and mirror ratios (:mod:`compare.felt_metrics`)
==============  ===============================================================================

Other code adds to a report through :func:`write_report`'s ``sections`` (a :class:`Section`:
its HTML, the figures it writes into ``figures/`` and the standard section it goes before),
as :mod:`compare.sweep` does with its "Parameter sweep" section; nothing splices HTML.

Written for a researcher: every figure has a caption (what is plotted, error bars and whether they
are smaller than the markers, the shaded beam-blocked cone around the labelled retro-direction,
the mirror direction); model lines are broken where the curve has no point (never drawn across
the beam-blocked gap); H is given in turns and degrees; swatches are labelled with the H, S, V of
the pixel shown; datasets are summarised in words (no link URLs with temporary ports); PNG at
:data:`FIGURE_DPI` (150) and, on request, SVG. Incomplete data and a dataset compared with itself
get a banner. The normalisation's uncertainty is explained and its effect on the overall NRMSE
(``k -+ u_k``) shown; ``metrics.json`` itself is unchanged (its NRMSE uses ``k``).

``write_report`` writes only into a new or empty folder or over a previous report (recognised by
the ``<meta name="generator">`` of its ``report.html``; only that report's files are replaced, its
figures that the new one does not draw removed); any other non-empty folder needs ``force``.

Figures (matplotlib, Agg backend, written to ``figures/`` and embedded in the HTML as base64 PNG):

The in-plane figures have the layout of the paper's Figure 7: one panel per incidence angle side
by side, the measurement as points with error bars, each simulation as a line with its own +-1
standard uncertainty shaded around it (``k u_C``; the luminance curve sums the wavelengths'
uncertainties linearly, the white Monte Carlo's errors being correlated across wavelengths).

``inplane_luminance.png``
    One panel per incidence angle present (0, 30, 45, 60 deg for the red-cotton plan), the
    luminance-weighted radiance coefficient ``Y[beta] / pi`` (the CIE ``Y`` of the spectrum
    under the report's illuminant, ``Y = 1`` for the ideal white diffuser, i.e. a band average
    weighted by what the eye sees) against the signed observation angle ``s``; measured as points
    with error bars (``u_Y / pi``, ``u_beta`` propagated through the linear ``Y`` weights), each
    simulation (normalised per wavelength) as a line.
``inplane_<W>nm.png``
    The same at single wavelengths: the shared wavelengths nearest 450, 550 and 650 nm
    (``beta / pi``, error bars ``u_beta / pi``).
``spectrum.png``
    Spectra at the colour geometry: left, the simulations normalised per wavelength; right, scaled
    by the one luminance factor ``k_Y`` used for the colour match (:mod:`compare.colourmatch`).
``factor.png``
    The normalisation factor ``k(lambda)`` of each simulation with its standard uncertainty.
``swatches.png``
    Colour swatches (display sRGB) of the measurement and each simulation at the colour geometry,
    labelled with the H, S, V of the displayed (gamma-encoded) pixel.
``colour_strips.png``
    The colour along every in-plane curve: per incidence, one strip per dataset, one swatch per
    observation angle (the dataset's own spectrum there -> linear sRGB via
    :mod:`gonio.data.colour`, scaled to the strip's brightest swatch, gamma-encoded for display);
    the caption gives the hue at both ends of each highest-incidence strip.

Simulated curves are drawn at the simulation's own in-plane geometries when its wavelength grid
contains the comparison grid (so points the instrument cannot measure, like the normal/normal one,
are shown), otherwise at the measured geometries (interpolated).

Every user-supplied string (sample names, paths, meta fields) is escaped with
:func:`html.escape` before it enters the HTML; in figure labels ``$`` is escaped so that
matplotlib does not read names as mathtext.
"""

from .build import write_report
from .curves import BEAM_BLOCK_DEG, REPORT_WAVELENGTHS_NM
from .figures import FIGURE_DPI, save_figure, swatch_entries
from .outdir import GENERATOR, prepare_out_dir
from .page import SECTION_KEYS, Section
from .prose import source_summary

__all__ = ["BEAM_BLOCK_DEG", "FIGURE_DPI", "GENERATOR", "REPORT_WAVELENGTHS_NM", "SECTION_KEYS",
           "Section", "prepare_out_dir", "save_figure", "source_summary", "swatch_entries",
           "write_report"]
