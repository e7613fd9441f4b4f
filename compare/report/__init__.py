"""The comparison report as a list of sections.

``report.html`` (one self-contained file), ``figures/*.png`` and ``metrics.json``.

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
``shape``       section "Shape ratios": opposition and mirror ratios (:mod:`compare.ratios`)
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

The figures and what each shows: :mod:`.figures`.

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
