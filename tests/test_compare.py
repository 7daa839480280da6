"""Twin vs measurement comparison: uncertainty combination, words, phase folding, yields, CLI."""
import math

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pandas as pd

from analysis.atomic_dir import MARKER
import pytest

from analysis import compare as cmpmod
from analysis.compare import (PredictionError, compare, phase_fold, track_velocity)
from analysis.config import PAPER_TABLE3_DIR
from analysis.measurements import Dataset, load_dataset, write_dataset
from analysis.plotting import compare_plots


def paper_predictions(rel_sd=0.02, n=3):
    """The paper's own DEM speeds as 'model' with a 2 % replicate sd; f_col = 2 f, no sd."""
    s = load_dataset(PAPER_TABLE3_DIR).summary
    rows = []
    for _, r in s.iterrows():
        v = float(r["v_mean_dem_paper_m_s"])
        rows.append((r["condition_id"], "v_mean_m_s", v, rel_sd * v, n))
        rows.append((r["condition_id"], "f_col_hz", float(r["f_col_hz"]), np.nan, 1))
    return pd.DataFrame(rows, columns=["condition_id", "observable", "mean", "sd",
                                       "n_replicates"])


def synthetic_dataset(n_cond=150, seed=0, v_sd=0.03, f_sd=0.8):
    rng = np.random.default_rng(seed)
    f = rng.uniform(20, 30, n_cond)
    d = rng.choice([17.5, 20.6], n_cond)
    cid = ["c%03d" % i for i in range(n_cond)]
    v_true = 0.09 * f - 0.02 * d
    fc_true = 2 * f
    cond = pd.DataFrame({"condition_id": cid, "frequency_hz": f, "ball_diameter_mm": d})
    summ = pd.DataFrame({"condition_id": cid, "v_mean_m_s": v_true + rng.normal(0, v_sd, n_cond),
                         "v_mean_sd_m_s": v_sd, "f_col_hz": fc_true + rng.normal(0, f_sd, n_cond),
                         "f_col_sd_hz": f_sd})
    ds = Dataset(name="synthetic", description="test", source="test", velocity_frame="lab",
                 conditions=cond, summary=summ)
    return ds, v_true, fc_true, rng


def _replicate_predictions(ds, v_true, fc_true, rng, n, rep_sd_v=0.06, rep_sd_f=1.5):
    rows = []
    for c, v, fc in zip(ds.conditions["condition_id"], v_true, fc_true):
        reps_v = v + rng.normal(0, rep_sd_v, n)
        reps_f = fc + rng.normal(0, rep_sd_f, n)
        rows.append((c, "v_mean_m_s", reps_v.mean(), reps_v.std(ddof=1), n))
        rows.append((c, "f_col_hz", reps_f.mean(), reps_f.std(ddof=1), n))
    return pd.DataFrame(rows, columns=["condition_id", "observable", "mean", "sd",
                                       "n_replicates"])


def test_three_replicates_need_pooling():
    own, pooled = [], []
    for seed in range(3):
        ds, v_true, fc_true, rng = synthetic_dataset(seed=4 + seed)
        pred = _replicate_predictions(ds, v_true, fc_true, rng, n=3)
        own.append(compare(ds, pred).chi2_dof)
        res = compare(ds, pred, pool_model_sd=True)
        pooled.append(res.chi2_dof)
    # pooled sd (300 dof): z standard normal; per-condition sd from 3 replicates (2 dof):
    # heavy tails, chi2/dof biased high
    assert np.mean(pooled) == pytest.approx(1.0, abs=0.15)
    assert np.mean(own) > np.mean(pooled) + 0.1
    v = res.table.loc[res.table["observable"] == "v_mean_m_s"]
    assert np.allclose(v["model_sd"] / v["model_mean"], (v["model_sd"] / v["model_mean"]).iat[0])


def test_uncertainty_combines_measurement_and_replicate_noise():
    ds, v_true, fc_true, rng = synthetic_dataset()
    n = 30          # replicate sd chosen so that the twin's se equals the measurement sd
    pred = _replicate_predictions(ds, v_true, fc_true, rng, n, rep_sd_v=0.03 * np.sqrt(n),
                                  rep_sd_f=0.8 * np.sqrt(n))
    res = compare(ds, pred)
    t = res.to_frame()
    assert len(t) == 300 and res.dof == 300
    # sigma = sqrt(sd_meas^2 + sd_rep^2 / n): the z are standard normal when the model is right
    assert np.mean(t["z"] ** 2) == pytest.approx(1.0, abs=0.2)
    assert abs(np.mean(t["z"])) < 0.15
    v = t.loc[t["observable"] == "v_mean_m_s"]
    assert np.allclose(v["sigma"], np.hypot(0.03, v["model_sd"] / np.sqrt(n)))
    # ignoring the replicate noise doubles chi2/dof: (0.03^2 + 0.03^2) / 0.03^2 = 2
    naive = np.mean((v["residual"] / 0.03) ** 2)
    assert naive == pytest.approx(2.0, abs=0.5)


def test_paper_table3_words_and_numbers():
    ds = load_dataset(PAPER_TABLE3_DIR)
    res = compare(ds, paper_predictions())
    t = res.table.set_index(["condition_id", "observable"])
    r = t.loc[("f22.5_d20.6", "v_mean_m_s")]
    sigma = np.hypot(0.015 * 1.86, 0.02 * 1.95 / np.sqrt(3))
    assert r["sigma"] == pytest.approx(sigma)
    assert r["z"] == pytest.approx((1.95 - 1.86) / sigma)
    assert r["rel_residual_pct"] == pytest.approx(100 * 0.09 / 1.86)
    assert r["measured_sd_default"] and not r["model_sd_default"]
    fc = t.loc[("f30_d17.5", "f_col_hz")]
    assert fc["model_sd_default"] and fc["model_sd"] == 1.0 and fc["z"] == 0.0
    lines = res.summary_lines(z_report=2.0)
    assert lines == ["20.6 mm ball at 22.5 Hz: speed 4.8 %% high (%.1f sigma)"
                     % ((1.95 - 1.86) / sigma)]
    assert "chi2/dof" in res.summary()
    assert res.chi2 == pytest.approx(np.sum(res.table["z"] ** 2))
    assert res.residuals.index.nlevels == 2
    by = res.chi2_by_observable()
    assert by.loc["f_col_hz", "chi2"] == 0.0


def test_missing_and_bad_predictions():
    ds = load_dataset(PAPER_TABLE3_DIR)
    pred = paper_predictions()
    res = compare(ds, pred.iloc[2:])
    assert set(res.missing) == {("f30_d17.5", "v_mean_m_s"), ("f30_d17.5", "f_col_hz")}
    assert len(res.table) == 14
    bad = pred.copy()
    bad.loc[3, "condition_id"] = "f31_d20.6"
    with pytest.raises(PredictionError, match="row 4.*unknown condition_id"):
        compare(ds, bad)
    bad = pred.copy()
    bad.loc[0, "sd"] = -0.1
    with pytest.raises(PredictionError, match="row 1.*negative sd"):
        compare(ds, bad)
    bad = pred.copy()
    bad.loc[0, "n_replicates"] = 0
    with pytest.raises(PredictionError, match="n_replicates"):
        compare(ds, bad)
    with pytest.raises(PredictionError, match="'sd' is missing"):
        compare(ds, pred.drop(columns="sd"))
    with pytest.raises(PredictionError, match="duplicate"):
        compare(ds, pd.concat([pred, pred.iloc[:1]]))


def _sine_track(f, amp, phase, fps=2134.0, dur=0.4, noise=0.0, rng=None):
    t = np.arange(int(dur * fps)) / fps
    x = amp * np.sin(2 * np.pi * f * t + phase)
    if noise:
        x = x + rng.normal(0, noise, t.size)
    return pd.DataFrame({"t_s": t, "x_m": x, "y_m": 0.001 * np.ones_like(t)})


def test_track_velocity_of_a_sinusoid():
    f, amp = 25.0, 0.01
    tr = _sine_track(f, amp, 0.3)
    v = track_velocity(tr)
    w = 2 * np.pi * f
    inner = slice(20, -20)
    expect = amp * w * np.cos(w * tr["t_s"] + 0.3)
    assert np.max(np.abs(v["vx_m_s"].to_numpy()[inner] - expect.to_numpy()[inner])) < 0.01 * amp * w
    assert np.allclose(v["vy_m_s"], 0.0, atol=1e-9)


def test_phase_folded_comparison_recovers_shift(tmp_path):
    ds = load_dataset(PAPER_TABLE3_DIR)
    rng = np.random.default_rng(1)
    f, amp, n_bins = 25.0, 0.0136, 24
    shift_true = 6                               # bins: the camera clock started 1/4 cycle late
    ds.tracks = {"f25_d20.6": _sine_track(f, amp, 2 * np.pi * shift_true / n_bins, noise=2e-5,
                                          rng=rng)}
    model = {"f25_d20.6": _sine_track(f, amp, 0.0)}
    res = compare(ds, paper_predictions(), model_tracks=model, n_phase_bins=n_bins)
    ph = res.phase
    assert set(ph["side"]) == {"measured", "model"}
    m = ph.loc[ph["side"] == "measured", "vx_mean_m_s"].to_numpy()
    p = ph.loc[ph["side"] == "model", "vx_mean_m_s"].to_numpy()
    assert ph["shift_bins"].iat[0] == shift_true
    assert np.max(np.abs(m - p)) < 0.03 * 2 * np.pi * f * amp
    assert np.max(p) == pytest.approx(2 * np.pi * f * amp, rel=0.03)
    fold = phase_fold(model["f25_d20.6"], f, n_bins)
    assert fold.shape == (n_bins, 6) and fold["n"].sum() == len(model["f25_d20.6"])


def test_yield_residuals():
    ds = load_dataset(PAPER_TABLE3_DIR)
    ds.yields = pd.DataFrame({"condition_id": ["f25_d20.6"] * 3, "time_min": [5.0, 10.0, 15.0],
                              "yield_pct": [10.0, 20.0, 40.0]})
    pred = paper_predictions()
    ypred = pd.DataFrame({"condition_id": "f25_d20.6", "observable": "yield_pct",
                          "time_min": [0.0, 20.0], "mean": [0.0, 40.0], "sd": [1.0, 1.0],
                          "n_replicates": [1, 1]})
    res = compare(ds, pd.concat([pred, ypred], ignore_index=True))
    y = res.table.loc[res.table["observable"] == "yield_pct"].set_index("time_min")
    assert list(y.index) == [5.0, 10.0, 15.0]
    assert np.allclose(y["model_mean"], [10.0, 20.0, 30.0])      # linear interpolation
    assert y.loc[15.0, "residual"] == -10.0
    assert y.loc[15.0, "sigma"] == pytest.approx(np.hypot(2.0, 1.0))
    assert any("yield at 15 min 10.0 points low" in s for s in res.summary_lines())


def test_plots_return_axes():
    import matplotlib.pyplot as plt
    ds = load_dataset(PAPER_TABLE3_DIR)
    res = compare(ds, paper_predictions())
    assert compare_plots.plot_residual_heatmap(res) is not None
    assert compare_plots.plot_phase_folded(res) is not None
    stair = pd.DataFrame({"stage": ["baseline", "calibrated", "with x"],
                          "chi2_dof": [9.0, 5.0, 1.0]})
    assert compare_plots.plot_chi2_staircase(stair) is not None
    plt.close("all")


def test_cli_writes_report(tmp_path, capsys):
    pred_csv = tmp_path / "pred.csv"
    paper_predictions().to_csv(pred_csv, index=False)
    ds = load_dataset(PAPER_TABLE3_DIR)
    ds.tracks = {"f25_d20.6": _sine_track(25.0, 0.0136, 1.0)}
    ds_dir = write_dataset(ds, tmp_path / "ds")
    (tmp_path / "mt").mkdir()
    _sine_track(25.0, 0.0136, 0.0).to_csv(tmp_path / "mt" / "f25_d20.6.csv", index=False)
    out = tmp_path / "out"
    rc = cmpmod.main(["--dataset", str(ds_dir), "--predictions", str(pred_csv), "--out",
                      str(out), "--model-tracks", str(tmp_path / "mt")])
    assert rc == 0
    assert {p.name for p in out.iterdir()} == {"comparison.csv", "comparison.md", "heatmap.png",
                                               "phase.png", MARKER}
    assert "speed 4.8 % high" in (out / "comparison.md").read_text()
    assert len(pd.read_csv(out / "comparison.csv")) == 16
    bad = paper_predictions()
    bad.loc[0, "condition_id"] = "nope"
    bad.to_csv(pred_csv, index=False)
    out2 = tmp_path / "out2"
    rc = cmpmod.main(["--dataset", str(ds_dir), "--predictions", str(pred_csv), "--out",
                      str(out2)])
    assert rc == 2 and not out2.exists()
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown condition_id" in err
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_impact_observables_of_jar_tracks_are_compared():
    """A track carrying the jar (exact impact map, e = 0.3) is read into impact observables;
    a prediction at the truth agrees, one with e = 0.2 fails in plain words, and the sigma of
    an impact observable holds one twin run's sd (a track is one realisation)."""
    from tests.test_flights import impact_map_track
    from analysis.flights import dataset_flights
    tr, _ = impact_map_track(e=0.3, frequency_hz=25.0)
    cond = pd.DataFrame({"condition_id": ["f25_d17.5"], "frequency_hz": [25.0],
                         "ball_diameter_mm": [17.5]})
    summ = pd.DataFrame({"condition_id": ["f25_d17.5"], "v_mean_m_s": [2.0],
                         "v_mean_sd_m_s": [0.03], "f_col_hz": [50.0], "f_col_sd_hz": [1.0]})
    ds = Dataset(name="jar", description="test", source="test", velocity_frame="lab",
                 conditions=cond, summary=summ, tracks={"f25_d17.5": tr})
    fl = dataset_flights(ds).set_index("observable")
    base = [("f25_d17.5", "v_mean_m_s", 2.0, 0.02, 2), ("f25_d17.5", "f_col_hz", 50.0, 1.0, 2)]

    def pred(e_app, run_sd=0.01):
        rows = base + [("f25_d17.5", k, float(fl.loc[k, "value"]), 0.0, 2)
                       for k in fl.index if k != "e_app"]
        rows.append(("f25_d17.5", "e_app", e_app, run_sd, 2))
        return pd.DataFrame(rows, columns=["condition_id", "observable", "mean", "sd",
                                           "n_replicates"])

    good = compare(ds, pred(0.3))
    t = good.table.set_index("observable")
    assert set(fl.index) <= set(t.index) and not good.missing
    assert abs(t.loc["e_app", "z"]) < 2
    assert t.loc["e_app", "one_realisation"] and not t.loc["v_mean_m_s", "one_realisation"]
    assert t.loc["e_app", "sigma"] == pytest.approx(
        math.sqrt(fl.loc["e_app", "sd"] ** 2 + 0.01 ** 2 + 0.01 ** 2 / 2))
    assert not np.isfinite(t.loc["e_app", "rel_residual_pct"])
    bad = compare(ds, pred(0.2))
    tb = bad.table.set_index("observable")
    assert tb.loc["e_app", "z"] < -5
    assert "apparent restitution" in bad.summary() and "0.102 low" in bad.summary()
    # without impact observables in the predictions the tracks are not read
    plain = compare(ds, pred(0.3).iloc[:2])
    assert list(plain.table["observable"]) == ["v_mean_m_s", "f_col_hz"]
    assert compare(ds, pred(0.3), flights=False).missing == ()
