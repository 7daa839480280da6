"""The output layer for text: every Markdown page the project writes is rendered here.

- :mod:`analysis.report.study_pages`: one page per study folder in results/ and the index
  results/README.md, read from the folders' committed files (``python -m analysis.report``,
  ``make report``; see that module for the behaviour).
- :mod:`analysis.report.stage_pages`: the pages the stages write into their own output folders
  (the loop's report.md, the demo's README.md, the open-world suite and the studies that keep
  a page). Each is a function from the results the stage has computed to the page's text; the
  stage writes it (atomically, inside its output folder) under the file name it always had.
- :mod:`analysis.report.loop_words`: what the loop's page, figures and loop.json say about its
  numbers, declared once (what each staircase stage is, which the verdict quotes, the chi2
  gain each candidate needed, the FAKE mark, the rule for an unconstrained parameter).
- :mod:`analysis.report.markdown`: the shared blocks (number formatting, tables, the
  SYNTHETIC banner, the atomic write of one file).

Figures are drawn by :mod:`analysis.plotting`; this layer only links them. The names of the
former module ``analysis/report.py`` stay importable from ``analysis.report``.

    python -m analysis.report [--results-dir DIR] [--strict]      # make report
"""
import os  # noqa: F401  (analysis.report.os: the file operations of the page writes)

from analysis.report.markdown import (fmt, fmt_signed, frame_table_lines, has_tabulate,
                                      is_number, md_table, synthetic_banner, write_atomic)
from analysis.report.stage_pages import (apparatus_identification_page, apparatus_screen_page,
                                         demo_page, frame_equivalence_page, loop_page,
                                         open_suite_page)
from analysis.report.study_pages import (EXTERNAL_PAGE_NAMES, EXTERNAL_PAGES, GENERATED_NOTE,
                                         GOAL_CAL_MAX_V_PCT, GOAL_CAL_MEAN_V_PCT, GOAL_CAL_RUNS,
                                         GOAL_OBS_FCOL_HZ, GOAL_OBS_RMS_PX, GOAL_OBS_V_PCT,
                                         GOAL_SURROGATE_LR_FCOL_PCT, GOAL_SURROGATE_LR_V_PCT,
                                         IGNORED_FOLDERS, OWN_PAGE_MARK, PAPER_TABLE4,
                                         PAPER_TABLE5, PNG_MAGIC, STUDIES, TWIN_TABLES_REQUIRED,
                                         PageResult, ReportInputError, Study, StudyFolder,
                                         build_reports, check_pages, main, page_calibration,
                                         page_kinetics, page_observe, page_predict,
                                         page_studies, page_surrogate, page_twin_tables,
                                         render_index, render_page)

__all__ = [
    # shared blocks
    "fmt", "fmt_signed", "frame_table_lines", "has_tabulate", "is_number", "md_table",
    "synthetic_banner", "write_atomic",
    # study pages and the index (python -m analysis.report)
    "EXTERNAL_PAGE_NAMES", "EXTERNAL_PAGES", "GENERATED_NOTE", "GOAL_CAL_MAX_V_PCT",
    "GOAL_CAL_MEAN_V_PCT", "GOAL_CAL_RUNS", "GOAL_OBS_FCOL_HZ", "GOAL_OBS_RMS_PX",
    "GOAL_OBS_V_PCT", "GOAL_SURROGATE_LR_FCOL_PCT", "GOAL_SURROGATE_LR_V_PCT",
    "IGNORED_FOLDERS", "OWN_PAGE_MARK", "PAPER_TABLE4", "PAPER_TABLE5", "PNG_MAGIC", "STUDIES",
    "TWIN_TABLES_REQUIRED", "PageResult", "ReportInputError", "Study", "StudyFolder",
    "build_reports", "check_pages", "main", "page_calibration", "page_kinetics",
    "page_observe", "page_predict", "page_studies", "page_surrogate", "page_twin_tables",
    "render_index", "render_page",
    # stage pages
    "apparatus_identification_page", "apparatus_screen_page", "demo_page",
    "frame_equivalence_page", "loop_page", "open_suite_page",
]
