"""The committed run table as a cache keyed by run id, and its near runs."""
import json

import numpy as np
import pandas as pd
import pytest

from analysis.config import twin_config
from analysis.twin_runs import BudgetError, TwinRuns, near_index, near_run

BASE = {"frequency_hz": 25.0, "ball_diameter_m": 0.0206, "restitution": 0.3283649639334533,
        "static_friction": 0.43253382617922387, "rolling_friction": 0.1,
        "amplitude_m": 0.012667432029828217, "seed": 50}


def _table(tmp_path, configs):
    """A committed run table of the given configs (their complete form, as meta.json holds
    it), each with made-up observables."""
    rows = []
    for k, c in enumerate(configs):
        full = twin_config.complete_config(dict(c))
        rows.append({"run_id": twin_config.run_id(full),
                     "config": json.dumps(full, sort_keys=True), "frame": "lab",
                     "v_mean_m_s": 2.0 + 0.1 * k, "v_mean_jar_m_s": 1.5, "f_col_hz": 50.0,
                     "motion_mode": "end_to_end"})
    p = tmp_path / "runs.csv"
    pd.DataFrame(rows).to_csv(p, index=False)
    return p, [r["run_id"] for r in rows]


def test_a_point_a_few_ulps_away_is_the_committed_run_and_a_real_move_is_not(tmp_path):
    """A fit redone on another machine gives the same point to 1e-5 (BLAS rounding) and so
    another run id: it is served by the committed run (its id, its observables), nothing runs
    and no budget is spent; a point 1e-3 away, another seed or another effect is a new run."""
    p, (rid,) = _table(tmp_path, [BASE])
    idx = near_index(pd.read_csv(p).set_index("run_id"))
    noisy = dict(BASE, restitution=BASE["restitution"] * (1 + 3.4e-6),
                 static_friction=BASE["static_friction"] * (1 + 1.5e-5))
    assert twin_config.run_id(twin_config.complete_config(noisy)) != rid
    assert near_run(noisy, idx) == rid
    assert near_run(dict(BASE, restitution=BASE["restitution"] * 1.001), idx) is None
    assert near_run(dict(noisy, seed=51), idx) is None
    assert near_run(dict(noisy, effects={"air_drag": {"drag_scale": 1.0}}), idx) is None
    twin = TwinRuns(runs_dir=tmp_path / "cache", run_table=p, budget_runs=0, progress=False,
                    log=lambda s: None)
    asked = pd.DataFrame({"config": [noisy], "point": [3]})
    plan = twin.plan(asked)
    assert (plan.committed, plan.new) == (1, 0)
    out = twin(asked)
    assert list(out["run_id"]) == [rid] and out["v_mean_m_s"].iloc[0] == pytest.approx(2.0)
    assert twin.new_runs == 0 and not (tmp_path / "cache").exists()
    far = pd.DataFrame({"config": [dict(BASE, restitution=0.4)], "point": [4]})
    assert twin.plan(far).new == 1
    with pytest.raises(BudgetError):
        twin(far)
    assert np.isfinite(out["f_col_hz"]).all()
