"""``python -m analysis.tracking``: the command line of :mod:`analysis.tracking.cli`."""
import sys

from analysis.tracking.cli import main

if __name__ == "__main__":
    sys.exit(main())
