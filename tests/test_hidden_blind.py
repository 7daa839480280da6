"""A blind hidden-effect case on the REAL twin (issue 6): YADE makes a dataset with an effect the
test does not tell diagnose; diagnose, with the committed signature library
(results/signatures) and the calibration's emulator, must name it, never the decoy, and adding it
must bring chi2/dof down to <= 1.5 (the ">= 3x" part of the goal is a suite figure: make
bench-hidden). Eight twin runs (one per Table-3 condition,
seeds the suite never uses), ~2 min on 2 cores."""
import json

import pytest

from analysis import twin_model
from analysis.hidden import make_hidden_dataset
from analysis.hidden_suite import score_case

pytestmark = [pytest.mark.yade, pytest.mark.slow]

# the hidden effect: an induction period of 1100 J (73 % of its diagnose range) acting on the
# yields of the twin's runs. Of the DEM effects none is found reliably at physical strengths
# against 1.5 % measurement noise (results/hidden_suite/README.md: arc motion at 70 % of its
# range is found 2 times in 5), so a blind DEM case would test luck, not the loop.
HIDDEN = {"induction_period": {"induction_energy_j": 1100.0}}


def test_blind_hidden_effect_is_found_on_the_real_twin(tmp_path):
    library = twin_model.load_library()
    model = twin_model.TwinModel(__import__("pandas").DataFrame(library[1]["conditions"]), {},
                                 library=library)
    ds, truth = make_hidden_dataset(
        "blind", HIDDEN, replicates=1, seed=4242, twin_seed=42, base_config=library[1]["theta_ref"],
        workers=2, runs_dir=tmp_path / "runs", out_dir=tmp_path / "ds",
        truth_dir=tmp_path / "truth", progress=False, **model.twin_scatter())
    row = score_case(ds, truth, {"library": library, "emulator": model.em})
    name = next(iter(HIDDEN))
    info = json.dumps(row, default=str, indent=1)
    assert row["shift_sigma_max"] >= 3, info
    assert row["rank1"] == name and row["reported"] == name, info
    assert not row["decoy_significant"], info
    assert row["chi2_dof_after_add"] <= 1.5, info
    assert row["chi2_dof_after_add"] < row["chi2_dof_calibrated"], info
