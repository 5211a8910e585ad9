"""The HTML page of a fit (``bubblefit report``, and the demo's page).

:func:`load_report_inputs` reads a fit result and the images it names;
:func:`write_fit_page` writes ``index.html`` with the photo, the fitted render, the
residual, the thickness map and its standard error, the profile with its error band, the
parameter table and the verdict in words (:mod:`bubblefit.report.figures` draws them).
"""

from .page import PAGE_FILES, ReportData, load_report_inputs, parameter_rows, verdict_lines, write_fit_page

__all__ = ["PAGE_FILES", "ReportData", "load_report_inputs", "parameter_rows", "verdict_lines", "write_fit_page"]
