"""Yield loader (clear errors) and the SYNTHETIC generator (consistency with the paper, recovery,
band coverage)."""
import json

import numpy as np
import pandas as pd
import pytest

from analysis import kinetics as kin
from analysis import yield_data as yd

TRUTH = yd.SyntheticYieldTruth()


@pytest.fixture(scope="module")
def energy():
    return yd.synthetic_energy_inputs(tuple(yd.DEFAULT_SCHEDULE_MIN))


@pytest.fixture
def dataset_dir(tmp_path, energy):
    cond, y, meta = yd.generate_synthetic_yields(energy=energy, seed=3)
    return yd.write_yield_dataset(tmp_path / "ds", cond, y, meta)


def _rewrite(path, name, mutate):
    df = pd.read_csv(path / name, dtype={"condition_id": str})
    df = mutate(df)
    df.to_csv(path / name, index=False)


# ---------------------------------------------------------------------------- loader
def test_roundtrip_and_synthetic_label(dataset_dir):
    ds = yd.load_yield_dataset(dataset_dir)
    assert ds.synthetic is True
    assert json.loads((dataset_dir / "dataset.json").read_text())["synthetic"] is True
    assert set(ds.yields["phase"].dropna()) <= set(yd.PHASES)
    assert len(ds.conditions) == 3 and ds.conditions["ball_diameter_mm"].eq(20.0).all()


@pytest.mark.parametrize("name, mutate, words", [
    ("yields.csv", lambda d: d.drop(columns="yield_pct"), ["yields.csv", "yield_pct"]),
    ("yields.csv", lambda d: d.assign(yield_pct=d["yield_pct"].where(d.index != 4)),
     ["row 6", "yield_pct"]),
    ("yields.csv", lambda d: d.assign(yield_pct=d["yield_pct"].where(d.index != 2, -1.0)),
     ["row 4", "outside"]),
    ("yields.csv", lambda d: d.assign(yield_pct=d["yield_pct"].where(d.index != 2, 100.5)),
     ["row 4", "outside"]),
    ("yields.csv", lambda d: d.assign(time_min=d["time_min"].where(d.index != 1, 99.0)),
     ["out of order", "time_min"]),
    ("yields.csv", lambda d: d.assign(time_min=d["time_min"].where(d.index != 0, -5.0)),
     ["row 2", "negative"]),
    ("yields.csv", lambda d: d.assign(condition_id=d["condition_id"].where(d.index != 3, "nope")),
     ["row 5", "unknown condition", "nope"]),
    ("yields.csv", lambda d: d.assign(phase=d["phase"].where(d.index != 0, "slurry")),
     ["row 2", "phase"]),
    ("conditions.csv", lambda d: d.assign(frequency_hz=-d["frequency_hz"]),
     ["conditions.csv", "frequency_hz", "> 0"]),
    ("conditions.csv", lambda d: d.drop(columns="ball_diameter_mm"), ["ball_diameter_mm"]),
])
def test_loader_errors_name_file_row_column(dataset_dir, name, mutate, words):
    _rewrite(dataset_dir, name, mutate)
    with pytest.raises(yd.YieldDataError) as err:
        yd.load_yield_dataset(dataset_dir)
    for w in words:
        assert w in str(err.value)


def test_loader_missing_files(tmp_path, dataset_dir):
    with pytest.raises(yd.YieldDataError, match="not found"):
        yd.load_yield_dataset(tmp_path / "absent")
    (dataset_dir / "yields.csv").unlink()
    with pytest.raises(yd.YieldDataError, match="yields.csv"):
        yd.load_yield_dataset(dataset_dir)


def test_cli_exit_code_on_bad_dataset(tmp_path, capsys):
    assert yd.main(["check", str(tmp_path / "absent")]) == 2
    assert "error" in capsys.readouterr().err


# ---------------------------------------------------------------------------- generator vs paper
def test_shipped_dataset_is_labelled_and_consistent_with_paper():
    ds = yd.load_yield_dataset(yd.SYNTHETIC_DATASET_DIR)
    assert ds.synthetic and "SYNTHETIC" in ds.meta["description"]
    y = ds.yields.merge(ds.conditions, on="condition_id")
    first_complete = y[y["phase"] == "complete"].groupby("frequency_hz")["time_min"].min()
    assert first_complete.to_dict() == {25.0: 40.0, 27.5: 25.0, 30.0: 20.0}
    # linear (powder) up to about 12.5 min at 30 Hz: still on the line's scale at 12.5 min
    f30 = y[y["frequency_hz"] == 30.0].set_index("time_min")
    assert (f30.loc[[2.5, 5.0, 7.5, 10.0], "phase"] == "powder").all()
    assert abs(f30.loc[12.5, "e_tot_j_true"] / TRUTH.powder_wax_j - 1) < 0.02


def test_true_model_hits_paper_statements(energy):
    p = energy.set_index("frequency_hz")["power_w"]
    t_complete_min = TRUTH.wax_complete_j / p / 60
    # complete reached before the paper's observation time, but after the previous sample
    assert 17.5 < t_complete_min[30.0] <= 20 and 22.5 < t_complete_min[27.5] <= 25
    assert 30 < t_complete_min[25.0] <= 40
    assert np.isclose(yd.true_yield_pct(TRUTH.wax_complete_j + 1), 100.0)
    x1 = yd.true_yield_pct(TRUTH.powder_wax_j - 1e-9)
    assert 35 < x1 < 45                       # "conversions up to approximately 40 %"


def test_fit_recovers_table4_line_and_boundaries_on_shipped_data():
    ds = yd.load_yield_dataset(yd.SYNTHETIC_DATASET_DIR)
    energy = kin.energy_for_conditions(ds.conditions, kin.table3_energy_inputs())
    data = kin.attach_cumulative_energy(ds.yields, energy)
    fit = kin.fit_kinetics(data["e_tot_j"], data["yield_pct"], phase=data["phase"], n_boot=0)
    assert abs(fit.line.params["a_pct_per_kj"] - TRUTH.slope_pct_per_kj) < 1.00
    assert abs(fit.line.params["b_pct"] - TRUTH.intercept_pct) < 1.70
    assert abs(fit.boundaries.powder_wax_j / TRUTH.powder_wax_j - 1) < 0.05
    assert abs(fit.boundaries.wax_complete_j / TRUTH.wax_complete_j - 1) < 0.05


def test_least_squares_boundaries_unbiased_over_draws(energy):
    """Without phase labels (continuous LS): median over draws within 5 % of the truth."""
    e1, e2 = [], []
    for s in range(40):
        _, y, _ = yd.generate_synthetic_yields(energy=energy, seed=1000 + s)
        b = kin.find_boundaries(y["e_tot_j_true"], y["yield_pct"], method="continuous", n_boot=0)
        e1.append(b.powder_wax_j)
        e2.append(b.wax_complete_j)
    assert abs(np.median(e1) / TRUTH.powder_wax_j - 1) < 0.05
    assert abs(np.median(e2) / TRUTH.wax_complete_j - 1) < 0.05


def test_r2_and_band_coverage_over_300_draws(energy):
    grid = np.array([1000.0, 2000.0, 3000.0, 4000.0])
    truth_line = yd.true_yield_pct(grid, TRUTH)
    rng = np.random.default_rng(99)
    ci_hit, pi_hit, a_hit, r2 = [], [], [], []
    for s in range(300):
        _, y, meta = yd.generate_synthetic_yields(energy=energy, seed=s)
        m = y["phase"].to_numpy() == "powder"
        line = kin.fit_powder_line(y["e_tot_j_true"][m], y["yield_pct"][m])
        p = line.predict(grid)
        new = truth_line + rng.normal(0, meta["truth"]["sigma_powder_pct"], grid.size)
        ci_hit.append((p["ci_lo"] <= truth_line) & (truth_line <= p["ci_hi"]))
        pi_hit.append((p["pi_lo"] <= new) & (new <= p["pi_hi"]))
        ci = line.conf_int()
        a_hit.append(ci.loc["a_pct_per_kj", "lower"] <= TRUTH.slope_pct_per_kj <= ci.loc["a_pct_per_kj", "upper"])
        r2.append(line.r2)
    assert 0.90 <= np.mean(ci_hit) <= 0.99
    assert 0.90 <= np.mean(pi_hit) <= 0.99
    assert 0.90 <= np.mean(a_hit) <= 0.99
    assert abs(np.mean(r2) - TRUTH.r2_target) < 0.01
    print(f"coverage ci {np.mean(ci_hit):.3f} pi {np.mean(pi_hit):.3f} a {np.mean(a_hit):.3f} "
          f"mean r2 {np.mean(r2):.4f}")
