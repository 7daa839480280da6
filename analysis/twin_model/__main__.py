"""``python -m analysis.twin_model``: the command line of :mod:`analysis.twin_model.cli`."""
import sys

from analysis.twin_model.cli import main

if __name__ == "__main__":
    sys.exit(main())
