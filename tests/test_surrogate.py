"""Surrogates: design, BVR, recovery of a known smooth truth, domain check, persistence."""
import numpy as np
import pandas as pd
import pytest
from sklearn.base import clone

from analysis import surrogate as sur

SMALL_GRID = {"n_estimators": [50], "max_depth": [None, 3], "min_samples_leaf": [1, 2]}


@pytest.fixture(scope="module")
def table():
    return sur.synthetic_twin_table(v_rel_sd=0.01, f_col_sd_hz=0.3, seed=7)


@pytest.fixture(scope="module")
def results(table):
    return sur.train_surrogates(table, kinds=("lr", "rf", "gp"), random_state=0,
                                rf_param_grid=SMALL_GRID)


def _truth_frame(f, d):
    v, fc = sur.synthetic_truth(f, d)
    return pd.DataFrame({"frequency_hz": f, "ball_diameter_m": d, "bvr": sur.bvr(d),
                         "v_mean_m_s": v, "f_col_hz": fc})


def test_bvr_and_design():
    assert np.isclose(sur.bvr(0.020), np.pi / 6 * 0.020 ** 3 / 25e-6)
    d = sur.design_27()
    assert len(d) == 27 and len({p[0] for p in d}) == 9 and len({p[1] for p in d}) == 3
    f = sorted({p[0] for p in d})
    assert f[0] == 20.0 and f[-1] == 30.0 and np.allclose(np.diff(f), 1.25)
    with pytest.raises(sur.SurrogateInputError):
        sur.bvr(0.05)          # a 50 mm ball does not fit a 25 mL jar
    with pytest.raises(sur.SurrogateInputError):
        sur.bvr(-0.01)


def test_split_and_metrics_shape(results, table):
    r = results["lr"]
    assert (r.predictions["split"] == "test").sum() == int(np.ceil(0.3 * len(table)))
    assert r.metrics.shape == (4, 4)
    assert r.residuals.shape == (len(table), 2)
    assert set(r.to_frame()["kind"]) == {"lr"}


def test_surrogates_recover_truth_at_validation_cases(results):
    f = np.array([c[0] for c in sur.VALIDATION_CASES])
    d = np.array([c[1] for c in sur.VALIDATION_CASES])
    val = _truth_frame(f, d)
    err = sur.validation_errors({k: r.model for k, r in results.items()}, val)
    assert list(err["ball_radius_mm"]) == [10.0, 10.0, 10.0]
    # noise is 1 % on v and ~0.6 % on f_col; LR and GP must be within 2x that of the truth
    for k in ("lr", "gp"):
        assert err[f"v_err_{k}_pct"].max() < 2.0
        assert err[f"fcol_err_{k}_pct"].max() < 2.0
    assert err[f"v_err_rf_pct"].max() < 10.0           # RF on 19 points: coarse but sane


def test_gp_predictive_sd_covers_truth(results):
    gp = results["gp"].model
    ff, dd = np.meshgrid(np.linspace(20.5, 29.5, 10), np.linspace(0.0145, 0.0204, 6))
    f, d = ff.ravel(), dd.ravel()
    mu, sd = gp.predict(np.column_stack([f, sur.bvr(d)]), return_std=True)
    v, fc = sur.synthetic_truth(f, d)
    z = np.abs(mu - np.column_stack([v, fc])) / sd
    assert mu.shape == sd.shape == (f.size, 2)
    assert np.mean(z < 1.96) > 0.85


def test_estimator_contract(table):
    X, Y = sur.features(table), sur.targets(table)
    for kind in ("lr", "rf", "gp"):
        est = sur.make_surrogate(kind, random_state=3, rf_param_grid=SMALL_GRID)
        c = clone(est)
        assert repr(c.get_params(deep=False)) == repr(est.get_params(deep=False))
        assert est.fit(X, Y) is est
        assert est.predict(X[:4]).shape == (4, 2)
    gp = sur.GPSurrogate(random_state=0).fit(X, Y)
    assert hasattr(gp, "gps_") and hasattr(gp, "scaler_")
    a = sur.GPSurrogate(random_state=0).fit(X, Y).predict(X)
    assert np.allclose(a, gp.predict(X))
    with pytest.raises(sur.SurrogateInputError):
        sur.make_surrogate("svm")


def test_learning_curve_error_falls(table):
    lc = sur.learning_curve(table, kinds=("lr", "gp"), train_sizes=[4, 18], n_repeats=4,
                            random_state=0, truth=sur.synthetic_truth)
    m = lc.groupby(["kind", "n_train"])["mape_pct"].mean()
    for k in ("lr", "gp"):
        assert m[(k, 18)] < m[(k, 4)]


def test_domain_check_range_and_hull():
    X = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    dc = sur.DomainCheck().fit(X)
    fl = dc.flags(np.array([[0.2, 0.2], [0.9, 0.9], [1.5, 0.0]]))
    assert list(fl["in_range"]) == [True, True, False]
    assert list(fl["in_hull"]) == [True, False, False]
    assert list(fl["out_of_domain"]) == [False, True, True]


def test_twin_table_validation(tmp_path, table):
    p = tmp_path / "t.csv"
    table.drop(columns=["bvr"]).to_csv(p, index=False)
    t = sur.load_twin_table(p)
    assert np.allclose(t["bvr"], table["bvr"])
    bad = table.copy()
    bad.loc[3, "v_mean_m_s"] = np.nan
    bad.to_csv(p, index=False)
    with pytest.raises(sur.SurrogateInputError, match="row 5, column 'v_mean_m_s'"):
        sur.load_twin_table(p)
    table.drop(columns=["f_col_hz"]).to_csv(p, index=False)
    with pytest.raises(sur.SurrogateInputError, match="f_col_hz"):
        sur.load_twin_table(p)
    neg = table.copy()
    neg.loc[0, "frequency_hz"] = -25
    neg.to_csv(p, index=False)
    with pytest.raises(sur.SurrogateInputError, match="row 2, column 'frequency_hz'"):
        sur.load_twin_table(p)


def test_replicates_averaged_per_design_point():
    runs = sur.synthetic_twin_table(n_replicates=3, seed=3)          # 81 runs, 27 points
    runs = runs.sample(frac=1.0, random_state=1).reset_index(drop=True)   # seeds interleaved
    avg = sur.average_replicates(runs)
    assert len(avg) == 27 and (avg["n_replicates"] == 3).all()
    first_seen = runs.drop_duplicates(["frequency_hz", "ball_diameter_m"])
    assert np.allclose(avg["frequency_hz"], first_seen["frequency_hz"])      # order kept
    assert np.allclose(avg["ball_diameter_m"], first_seen["ball_diameter_m"])
    for _, row in avg.iterrows():
        reps = runs[np.isclose(runs["frequency_hz"], row["frequency_hz"])
                    & np.isclose(runs["ball_diameter_m"], row["ball_diameter_m"])]
        assert len(reps) == 3
        assert np.isclose(row["v_mean_m_s"], reps["v_mean_m_s"].mean())
        assert np.isclose(row["f_col_hz"], reps["f_col_hz"].mean())
        assert np.isclose(row["v_mean_sd_m_s"], reps["v_mean_m_s"].std())
        assert row["run_id"].split("/") == list(reps["run_id"])
    # one row per point: unchanged apart from the added columns; idempotent
    again = sur.average_replicates(avg)
    pd.testing.assert_frame_equal(again, avg)
    single = sur.synthetic_twin_table(seed=3)
    one = sur.average_replicates(single)
    assert (one["n_replicates"] == 1).all() and one["v_mean_sd_m_s"].isna().all()
    pd.testing.assert_frame_equal(one[single.columns], single)
    with pytest.raises(sur.SurrogateInputError, match="n_replicates"):
        sur.average_replicates(pd.concat([avg, avg.iloc[:1]]))


def test_training_on_runs_equals_training_on_means():
    runs = sur.synthetic_twin_table(n_replicates=3, seed=4)
    res_runs = sur.train_surrogates(runs, kinds=("lr",), random_state=0)["lr"]
    res_means = sur.train_surrogates(sur.average_replicates(runs), kinds=("lr",),
                                     random_state=0)["lr"]
    pred = res_runs.predictions
    assert len(pred) == 27 and (pred["n_replicates"] == 3).all()      # split over points
    assert (pred["split"] == "test").sum() == int(np.ceil(0.3 * 27))
    pd.testing.assert_frame_equal(pred, res_means.predictions)
    b = sur.fit_bundle(runs, kinds=("lr",))
    assert b.n_runs == 81 and b.extra["n_points"] == 27


def test_bundle_roundtrip_and_domain_flag(tmp_path, table):
    b = sur.fit_bundle(table, kinds=("lr", "gp"))
    path = b.save(tmp_path / "s.joblib")
    back = sur.SurrogateBundle.load(path)
    p1 = b.predict([25.0, 40.0], 0.020, kind="gp")
    p2 = back.predict([25.0, 40.0], 0.020, kind="gp")
    pd.testing.assert_frame_equal(p1, p2)
    assert list(p1["out_of_domain"]) == [False, True]
    assert {"v_mean_sd_m_s", "f_col_sd_hz"} <= set(p1.columns)
    # a smaller jar raises BVR beyond the trained range -> flagged
    assert bool(b.predict(25.0, 0.020, jar_volume_m3=15e-6)["out_of_domain"].iloc[0])
    with pytest.raises(sur.SurrogateInputError):
        sur.SurrogateBundle.load(tmp_path / "missing.joblib")


def test_table3_stand_in():
    t = sur.table3_twin_table()
    assert len(t) == 8 and t["source"].str.contains("Table 3").all()


def test_cli_synthetic(tmp_path, capsys):
    out = tmp_path / "s"
    assert sur.main(["--synthetic", "--kinds", "lr", "gp", "--lc-repeats", "1",
                     "--out", str(out)]) == 0
    for name in ("metrics.csv", "validation_errors.csv", "learning_curve.csv", "surrogate.joblib",
                 "surrogate_lr.json", "fig13_parity.png", "fig_learning_curve.png"):
        assert (out / name).is_file()
    assert sur.main(["--twin-table", str(tmp_path / "nope.csv"), "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
