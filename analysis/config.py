"""Path registry: every path the project uses, from the repository root. No absolute paths."""
from pathlib import Path
import sys

REPO_ROOT = Path(__file__).resolve().parent.parent
YADE_SCRIPTS_DIR = REPO_ROOT / "yade_scripts"
MILL_SCRIPT = YADE_SCRIPTS_DIR / "mill.py"
GEOMETRY_DIR = REPO_ROOT / "geometry"
DEFAULT_STL = GEOMETRY_DIR / "mm400_25ml.stl"
DATA_DIR = REPO_ROOT / "data"
MEASUREMENTS_DIR = DATA_DIR / "measurements"
PAPER_TABLE3_DIR = MEASUREMENTS_DIR / "paper_table3"
RESULTS_DIR = REPO_ROOT / "results"
RUNS_DIR = RESULTS_DIR / "runs"
#: run folders of the FAKE analytic twin (tests, demonstrations): never mixed with real runs,
#: which share their run ids
FAKE_RUNS_DIR = RESULTS_DIR / "runs_fake"
#: tracks of datasets' films, cached by the film's content hash (analysis.videos)
TRACK_CACHE_DIR = RESULTS_DIR / "track_cache"
DEMO_DIR = RESULTS_DIR / "demo"
#: the twin of the paper's mill (docs/apparatus.md): run-config fragments written by
#: analysis.studies.apparatus_identification - the apparatus identified from the paper's EDEM
#: column at its contact parameters, and the contact + apparatus calibrated on Table 3
PAPER_APPARATUS_PROFILE = RESULTS_DIR / "apparatus" / "paper_apparatus.json"
MEASURED_APPARATUS_PROFILE = RESULTS_DIR / "apparatus" / "measured_apparatus.json"
STUDIES_DIR = RESULTS_DIR / "studies"
CALIBRATION_DIR = RESULTS_DIR / "calibration"
KINETICS_DIR = RESULTS_DIR / "kinetics"
SURROGATE_DIR = RESULTS_DIR / "surrogate"
OBSERVE_DIR = RESULTS_DIR / "observe"

# the run-config declaration is shared with the YADE scene (stdlib only)
if str(YADE_SCRIPTS_DIR) not in sys.path:
    sys.path.insert(0, str(YADE_SCRIPTS_DIR))
import twin_config  # noqa: E402  (re-exported: analysis.config.twin_config)
