"""Blind hidden-effect case on the REAL twin (issue 6): a dataset the real twin made with an
effect the test does not tell diagnose (results/hidden_blind/visco_k0.4, made by
``python -m analysis.studies.hidden_blind_data``: one twin run per Table-3 condition, seeds the
suite never uses, measurement noise, a ball+jar track per condition); diagnose, with the
committed signature library (results/signatures) and the calibration's emulators, must name it,
never the decoy, and adding it must bring chi2/dof down to <= 1.5 (the ">= 3x" part of the goal
is a suite figure: make bench-hidden). The dataset is committed, so no YADE run is needed here
(its 8 twin runs took about 2 min of every make test); the truth is read only to score. The
diagnosis reads the impact observables of the tracks (analysis.flights) beside v_mean, f_col and
the yields."""
import json

import pytest

from analysis import twin_model
from analysis.hidden_suite import score_case
from analysis.studies.hidden_blind_data import CASES, OUT_DIR


@pytest.mark.parametrize("name", sorted(CASES))
def test_blind_hidden_effect_is_found_on_the_real_twin(name):
    ds, truth = OUT_DIR / name, OUT_DIR / "truth" / ("%s.truth.json" % name)
    library = twin_model.load_library()
    model = twin_model.TwinModel(__import__("pandas").DataFrame(library[1]["conditions"]), {},
                                 library=library)
    row = score_case(ds, truth, {"library": library, "emulator": model.em})
    hidden = next(iter(CASES[name][0]))
    info = json.dumps(row, default=str, indent=1)
    # 8 conditions x (v_mean, f_col, 4 yields, 5 impact observables of the jar track)
    assert row["n_observables"] == 8 * (2 + 4 + 5), info
    assert row["shift_sigma_max"] >= 3, info
    assert row["rank1"] == hidden and row["reported"] == hidden, info
    assert not row["decoy_significant"], info
    assert row["chi2_dof_after_add"] <= 1.5, info
    assert row["chi2_dof_after_add"] < row["chi2_dof_calibrated"], info


def test_blind_dataset_was_made_by_the_real_twin():
    """The committed dataset's truth names real twin runs (not the fake twin) at the library's
    anchor, one per Table-3 condition."""
    for name in CASES:
        t = json.loads((OUT_DIR / "truth" / ("%s.truth.json" % name)).read_text())
        assert len(t["run_ids"]) == 8
        assert t["effects"] == CASES[name][0]
        assert "fake" not in json.dumps(t.get("base_config", {}))
