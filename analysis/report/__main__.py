"""``python -m analysis.report``: the study pages and the index (:mod:`analysis.report`)."""
import sys

from analysis.report import main

sys.exit(main())
