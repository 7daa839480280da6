"""Blind hidden-effect cases on the REAL twin (issue 6): YADE makes a dataset with an effect the
test does not tell diagnose; diagnose, with the committed signature library
(results/signatures) and the calibration's emulators, must name it, never the decoy, and adding
it must bring chi2/dof down to <= 1.5 (the ">= 3x" part of the goal is a suite figure: make
bench-hidden). Eight twin runs per case (one per Table-3 condition, seeds the suite never uses),
~2 min each on 2 cores. The datasets carry a track of the ball and the jar per condition, so the
diagnosis reads the impact observables (analysis.flights) beside v_mean, f_col and the yields."""
import json

import pytest

from analysis import twin_model
from analysis.hidden import make_hidden_dataset
from analysis.hidden_suite import score_case

pytestmark = [pytest.mark.yade, pytest.mark.slow]

# the hidden effect: a viscoelastic wall, k = 0.4 (67 % of its range; a DEM case: found through
# the apparent restitution of the jar tracks, which v_mean and f_col alone could not do - the
# recalibrated restitution absorbed it). The kinetics case (an induction period of 1100 J on
# the twin's own energies) moved to tests/test_open_world_blind.py, where it runs at 6
# conditions the paper never ran from committed twin runs (no YADE: 2 min of make test saved).
CASES = [({"viscoelastic_restitution": {"k": 0.4}}, 4343, 43)]


@pytest.mark.parametrize("HIDDEN,seed,twin_seed", CASES,
                         ids=[next(iter(c[0])) for c in CASES])
def test_blind_hidden_effect_is_found_on_the_real_twin(tmp_path, HIDDEN, seed, twin_seed):
    library = twin_model.load_library()
    model = twin_model.TwinModel(__import__("pandas").DataFrame(library[1]["conditions"]), {},
                                 library=library)
    ds, truth = make_hidden_dataset(
        "blind", HIDDEN, replicates=1, seed=seed, twin_seed=twin_seed,
        base_config=library[1]["theta_ref"],
        workers=2, runs_dir=tmp_path / "runs", out_dir=tmp_path / "ds",
        truth_dir=tmp_path / "truth", progress=False, **model.twin_scatter())
    row = score_case(ds, truth, {"library": library, "emulator": model.em})
    name = next(iter(HIDDEN))
    info = json.dumps(row, default=str, indent=1)
    # 8 conditions x (v_mean, f_col, 4 yields, 5 impact observables of the jar track)
    assert row["n_observables"] == 8 * (2 + 4 + 5), info
    assert row["shift_sigma_max"] >= 3, info
    assert row["rank1"] == name and row["reported"] == name, info
    assert not row["decoy_significant"], info
    assert row["chi2_dof_after_add"] <= 1.5, info
    assert row["chi2_dof_after_add"] < row["chi2_dof_calibrated"], info
