"""Calibration recovers known parameters from synthetic data made by the (fake) twin."""
import numpy as np
import pandas as pd
import pytest
from threadpoolctl import threadpool_limits

from analysis import calibrate as cal
from analysis.config import PAPER_TABLE3_DIR
from analysis.emulator import GPEmulator
from analysis.fake_twin import FAKE_FCOL_SD_HZ, FAKE_V_REL_SD, simulate_fake, toy_observables

TRUTH = {"restitution": 0.35, "static_friction": 0.5, "rolling_friction": 0.3,
         "amplitude_m": 0.0135}


@pytest.fixture(autouse=True)
def one_blas_thread():
    with threadpool_limits(1):
        yield


def _synthetic_measurements(truth, seed=4242):
    meas = cal.load_measurements(PAPER_TABLE3_DIR)
    runs = simulate_fake(cal.condition_configs(truth, meas, seed=seed))
    meas["v_mean_m_s"] = runs["v_mean_m_s"].to_numpy()
    meas["f_col_hz"] = runs["f_col_hz"].to_numpy()
    # the "measurement" is one twin run: its scatter is the twin's replicate noise, which the
    # emulator's nugget already carries, so no extra measurement variance
    meas["v_mean_sd_m_s"] = 0.0
    meas["f_col_sd_hz"] = 0.0
    return meas


def _exact_posterior(meas, n=300_000, seed=0):
    """Posterior mean and sd of the true toy model by importance sampling from the prior."""
    names = list(cal.CALIBRATED)
    rng = np.random.default_rng(seed)
    th = np.column_stack([rng.uniform(*cal.CALIBRATED[k], n) for k in names])
    f = meas["frequency_hz"].to_numpy()[None]
    d = meas["ball_diameter_m"].to_numpy()[None]
    v, fc = toy_observables(*[th[:, i:i + 1] for i in range(4)], f, d)
    sv = FAKE_V_REL_SD * v
    ll = (-0.5 * (((meas["v_mean_m_s"].to_numpy() - v) / sv) ** 2 + 2 * np.log(sv)).sum(1)
          - 0.5 * (((meas["f_col_hz"].to_numpy() - fc) / FAKE_FCOL_SD_HZ) ** 2).sum(1))
    w = np.exp(ll - ll.max())
    w /= w.sum()
    mu = w @ th
    sd = np.sqrt(w @ (th - mu) ** 2)
    return pd.Series(mu, index=names), pd.Series(sd, index=names)


def test_load_paper_table3():
    meas = cal.load_measurements(PAPER_TABLE3_DIR)
    assert len(meas) == 8 and meas.attrs["velocity_frame"] == "lab"
    assert np.allclose(sorted(meas["ball_diameter_m"].unique()), [0.0175, 0.0206])
    assert (meas["f_col_hz"] == 2 * meas["frequency_hz"]).all()


def test_calibration_recovers_truth_within_interval():
    meas = _synthetic_measurements(TRUTH)
    res = cal.calibrate(simulate_fake, meas, n_initial=24, n_refine=8, n_rounds=1,
                        n_validation=2, n_steps=1500, burn=500, random_state=1)
    cover = res.covers(TRUTH)
    assert cover.all(), res.to_frame()
    # the emulator + MCMC posterior is the exact Bayesian posterior of the true toy model
    mu, sd = _exact_posterior(meas)
    assert ((res.params - mu).abs() < 0.5 * sd).all(), (res.params, mu, sd)
    assert ((res.stderr / sd > 0.75) & (res.stderr / sd < 1.33)).all(), (res.stderr, sd)
    # the data are informative: the jar amplitude is pinned well inside its prior
    assert res.stderr["amplitude_m"] < 0.1 * (0.016 - 0.010)
    assert res.n_parameter_sets == 24 + 8 + 1
    assert res.n_runs == (24 + 8) * 8 + 2 * 8
    # emulator error is near the twin's own replicate noise (1.5 % of v)
    assert res.loo.loc["v_mean_m_s", "rel_rmse_pct"] < 3 * 100 * FAKE_V_REL_SD
    assert abs(res.loo.loc["f_col_hz", "noise_sd"] - FAKE_FCOL_SD_HZ) < 0.5 * FAKE_FCOL_SD_HZ
    # twin at the posterior mean reproduces the synthetic measurements within the noise
    v_err = res.comparison["v_err_pct"].abs()
    assert v_err.max() < 4 * 100 * FAKE_V_REL_SD
    frame = res.to_frame()
    assert list(frame.columns[:5]) == ["mean", "sd", "q2.5", "q50", "q97.5"]
    assert (frame["q2.5"] >= frame["prior_lower"]).all()
    assert res.samples.shape[1] == 4


def test_emulator_noise_and_loo_on_known_function():
    rng = np.random.default_rng(0)
    X = rng.random((120, 2))
    f = np.sin(3 * X[:, 0]) + X[:, 1] ** 2
    noise = 0.05
    y = f + noise * rng.standard_normal(len(f))
    em = GPEmulator({"a": (0, 1), "b": (0, 1)}, outputs=("y",), random_state=0).fit(X, y)
    assert abs(em.noise_sd()[0] - noise) < 0.3 * noise
    assert 0.85 <= em.loo_.loc["y", "coverage95"] <= 1.0
    Xt = rng.random((200, 2))
    m, s = em.predict(Xt, return_std=True, include_noise=False)
    ft = np.sin(3 * Xt[:, 0]) + Xt[:, 1] ** 2
    assert np.sqrt(np.mean((m[:, 0] - ft) ** 2)) < noise       # mean beats one noisy run
    assert np.mean(np.abs(m[:, 0] - ft) <= 1.96 * s[:, 0]) > 0.85
    with pytest.raises(ValueError, match="not finite"):
        GPEmulator({"a": (0, 1), "b": (0, 1)}, outputs=("y",)).fit(X, np.r_[y[:-1], np.nan])


def test_observation_function_frames():
    tab = pd.DataFrame({"v_mean_m_s": [2.0], "v_mean_jar_m_s": [1.5], "f_col_hz": [50.0]})
    assert cal.observe(tab, "lab")["v_mean_m_s"].iloc[0] == 2.0
    assert cal.observe(tab, "jar")["v_mean_m_s"].iloc[0] == 1.5


@pytest.mark.parametrize("fname,text,match", [
    ("summary.csv", "condition_id,v_mean_m_s\nf25_d20.6,2.1\n", r"summary.csv.*f_col_hz.*missing"),
    ("summary.csv", "condition_id,v_mean_m_s,f_col_hz\nf25_d20.6,,50\n",
     r"summary.csv.*v_mean_m_s"),
    ("conditions.csv", "condition_id,frequency_hz,ball_diameter_mm\nf25_d20.6,-25,20.6\n",
     r"conditions.csv.*frequency_hz"),
])
def test_bad_measurements_raise_clear_error(tmp_path, fname, text, match):
    for f in ("dataset.json", "conditions.csv", "summary.csv"):
        (tmp_path / f).write_text((PAPER_TABLE3_DIR / f).read_text())
    (tmp_path / fname).write_text(text)
    with pytest.raises(cal.MeasurementError, match=match):
        cal.load_measurements(tmp_path)


def test_cli_bad_dataset_exit_2(tmp_path, capsys):
    assert cal.main(["--fake", "--dataset", str(tmp_path / "nope"),
                     "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


def test_camera_operator_on_a_recording(tmp_path):
    """A ball flying end to end at 2 m/s over 20 mm in a jar at rest: v = 2 m/s, f_col =
    100 /s, through the measurement's own operator (analysis.observe)."""
    import json
    fps, v, span = 2134.0, 2.0, 0.02
    t = np.arange(0, 0.5, 1 / fps)
    phase = (v * t / span) % 2.0
    x = span * np.where(phase < 1, phase, 2 - phase) - span / 2
    vx = np.where(phase < 1, v, -v)
    zeros = np.zeros_like(t)
    run = tmp_path / "run"
    run.mkdir()
    pd.DataFrame({"t_s": t, "x_m": x, "y_m": zeros, "z_m": zeros, "vx_m_s": vx,
                  "vy_m_s": zeros, "vz_m_s": zeros, "wx_rad_s": zeros, "wy_rad_s": zeros,
                  "wz_rad_s": zeros, "jar_x_m": zeros, "jar_vx_m_s": zeros}).to_csv(
        run / "trajectory.csv", index=False)
    meta = {"config": {"frequency_hz": 50.0, "ball_diameter_m": 0.0206,
                       "ball_density_kg_m3": 7800.0, "output_fps": fps},
            "summary": {"v_mean_m_s": 9.9, "v_mean_jar_m_s": 9.9, "f_col_hz": 9.9},
            "record_start_s": 0.0, "ball_mass_kg": 0.0357}
    (run / "meta.json").write_text(json.dumps(meta))
    pd.DataFrame(columns=["event_id", "t_start_s", "t_end_s", "vn_in_m_s", "vt_in_m_s",
                          "vn_out_m_s", "fn_peak_n", "e_diss_j", "where", "x_contact_jar_m",
                          "n_facets"]).to_csv(run / "impacts.csv", index=False)
    tab = pd.DataFrame({"run_dir": [str(run)], "v_mean_m_s": [9.9], "f_col_hz": [9.9]})
    cam = cal.observe(tab, "lab", operator="camera")
    assert abs(cam["v_mean_m_s"].iloc[0] - v) < 0.02 * v
    assert abs(cam["f_col_hz"].iloc[0] - v / span) <= 1 / 0.5 + 1e-9   # +-1 impact per record
    assert cal.observe(tab, "lab", operator="summary")["v_mean_m_s"].iloc[0] == 9.9
    with pytest.raises(ValueError, match="operator"):
        cal.observe(tab, "lab", operator="video")


def test_free_parameters_parse_and_stay_inside_declared_ranges():
    assert cal.parse_free(None) == cal.CALIBRATED
    b = cal.parse_free(["amplitude_m", "jar_inner_diameter_m=0.026:0.030"])
    assert b == {"amplitude_m": cal.APPARATUS["amplitude_m"],
                 "jar_inner_diameter_m": (0.026, 0.030)}
    for bad, msg in [(["jar_volume"], "not a calibratable"),
                     (["amplitude_m=0.005:0.012"], "leaves the declared range"),
                     (["amplitude_m=0.012"], "LO:HI"),
                     (["amplitude_m=0.014:0.012"], "LO < HI"),
                     (["amplitude_m", "amplitude_m"], "twice")]:
        with pytest.raises(ValueError, match=msg):
            cal.parse_free(bad)


def test_cli_free_and_set_clash_or_unknown_is_exit_2_without_output(tmp_path, capsys):
    out = tmp_path / "out"
    assert cal.main(["--fake", "--out", str(out), "--free", "bogus_m"]) == 2
    assert "bogus_m" in capsys.readouterr().err
    assert cal.main(["--fake", "--out", str(out), "--free", "amplitude_m",
                     "--set", "amplitude_m=0.013"]) == 2
    assert "amplitude_m" in capsys.readouterr().err
    assert not out.exists()


def test_identification_page_and_profile_from_a_calibration(tmp_path, capsys):
    """A calibration with an apparatus parameter free and a base profile (FAKE twin, small
    budget) -> the fixed keys recorded (the profile's, less the freed ones), the study page,
    the posterior correlations and the profile the demo reads."""
    import json
    from analysis.studies import apparatus_identification as ai
    base_prof = tmp_path / "base.json"
    base_prof.write_text(json.dumps({"config": {"rolling_friction": 0.3, "amplitude_m": 0.0141,
                                                "static_friction": 0.6}}))
    out = tmp_path / "cal"
    assert cal.main(["--fake", "--out", str(out), "--free", "amplitude_m",
                     "--free", "restitution", "--base-profile", str(base_prof),
                     "--set", "static_friction=0.5",
                     "--n-initial", "12", "--rounds", "0", "--n-validation", "2"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["base_config"] == {"rolling_friction": 0.3, "static_friction": 0.5}
    assert summary["bounds"]["amplitude_m"] == list(cal.APPARATUS["amplitude_m"])
    prof = tmp_path / "profile.json"
    assert ai.main(["--cal", str(out), "--profile", str(prof)]) == 0
    p = json.loads(prof.read_text())
    assert set(p["free"]) == {"amplitude_m", "restitution"}
    assert set(p["config"]) == {"amplitude_m", "restitution", "rolling_friction",
                                "static_friction"}
    assert p["config"]["rolling_friction"] == 0.3
    lo, hi = cal.APPARATUS["amplitude_m"]
    assert lo <= p["config"]["amplitude_m"] <= hi
    page = (out / "README.md").read_text()
    assert "mean |diff|" in page and "amplitude_m" in page
    assert (out / "posterior_correlation.csv").exists()
    base_prof.write_text(json.dumps({"nothing": 1}))
    assert cal.main(["--fake", "--out", str(tmp_path / "c2"), "--base-profile",
                     str(base_prof)]) == 2
    assert "config" in capsys.readouterr().err
