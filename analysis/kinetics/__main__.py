"""``python -m analysis.kinetics``: runs the kinetics command line (:mod:`analysis.kinetics.cli`)."""
import sys

from analysis.kinetics.cli import main

if __name__ == "__main__":
    sys.exit(main())
