"""Calibration recovers known parameters from synthetic data made by the (fake) twin."""
import numpy as np
import pandas as pd
import pytest
from threadpoolctl import threadpool_limits

from analysis import calibrate as cal
from analysis.demo import measured_table
from analysis.config import PAPER_TABLE3_DIR
from analysis.emulator import GPEmulator
from analysis.fake_twin import FAKE_FCOL_SD_HZ, FAKE_V_REL_SD

TRUTH = {"restitution": 0.35, "static_friction": 0.5, "rolling_friction": 0.3,
         "amplitude_m": 0.0135}


@pytest.fixture(autouse=True)
def one_blas_thread():
    with threadpool_limits(1):
        yield


def test_load_paper_table3():
    meas = measured_table(PAPER_TABLE3_DIR)
    assert len(meas) == 8 and meas.attrs["velocity_frame"] == "lab"
    assert np.allclose(sorted(meas["ball_diameter_m"].unique()), [0.0175, 0.0206])
    assert (meas["f_col_hz"] == 2 * meas["frequency_hz"]).all()


@pytest.mark.slow
def test_calibration_on_the_loops_emulator_covers_the_truth(tmp_path):
    """FAKE data at 8 conditions made at a known contact set and stroke: the posterior sampled
    on the loop's emulator (after its waves, focus wave and twin rerun) holds every true value
    in its 95 % interval, its sd is of the size of the fit's curvature se, the twin rerun at
    the fit reproduces the data within the noise, and the tables say what they hold."""
    from analysis.fake_twin import run_fake_twin
    from analysis.hidden import make_hidden_dataset
    from analysis.measurements import load_dataset
    from analysis.twin_runs import TwinRuns
    conds = pd.DataFrame({"condition_id": ["w%d" % i for i in range(8)],
                          "frequency_hz": [20.0, 21.5, 23.0, 24.5, 26.0, 27.5, 29.0, 32.0],
                          "ball_diameter_mm": [15, 17.5, 19, 20.6, 21.5, 17.5, 15, 20.6]})
    ds_dir, _ = make_hidden_dataset(
        "cal", {}, conditions=conds, replicates=1, seed=11, runner=run_fake_twin,
        base_config=dict(TRUTH), runs_dir=tmp_path / "runs", out_dir=tmp_path / "ds",
        truth_dir=tmp_path / "truth", twin_v_rel_sd=FAKE_V_REL_SD,
        twin_f_col_sd_hz=FAKE_FCOL_SD_HZ, progress=False, v_rel_sd=0.003, yield_times_min=())
    twin = TwinRuns(runner=run_fake_twin, runs_dir=tmp_path / "runs", workers=1,
                    progress=False)
    s = cal.calibration_settings(points=14, waves=0, focus_points=3, rerun_replicates=2,
                                 confirm_rounds=1, interval_rounds=0)
    res = cal.calibrate(load_dataset(ds_dir), s, twin=twin, n_steps=300, burn=100,
                        progress=False, log=lambda m: None)
    frame = res.to_frame()
    assert sorted(frame.index) == sorted(cal.CALIBRATED)
    assert res.covers(TRUTH).all(), frame
    ratio = frame["sd"] / frame["fit_se"]
    assert ((ratio > 0.4) & (ratio < 2.5)).all(), frame
    assert (frame["q2.5"] >= frame["prior_lower"]).all()
    assert (frame["q97.5"] <= frame["prior_upper"]).all()
    assert res.samples.shape == (32 * 200, 4)
    assert 0.1 < res.acceptance < 0.8
    c = res.comparison
    assert list(c["condition_id"]) == list(conds["condition_id"])
    # the data are one twin realisation (chaos FAKE_V_REL_SD) with 0.3 % measurement noise,
    # the rerun a mean of 2 seeds: their difference has sd sqrt(1.5^2 + 1.5^2 / 2 + 0.3^2) %
    # = 1.86 %; every condition within 4 of those (6.0 % was 3.2 of them: a 1 % event over 8
    # conditions, met at 6.01 % where the GP's fit differs in the last digits)
    diff_sd = 100 * np.sqrt(FAKE_V_REL_SD ** 2 * (1 + 1 / 2) + 0.003 ** 2)
    assert c["v_err_pct"].abs().max() < 4 * diff_sd
    assert set(res.design["wave"].astype(str)) == {"0", "focus", "confirm 1"}
    assert res.n_runs == len(res.design) and res.new_runs > 0


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
        measured_table(tmp_path)


def test_cli_bad_dataset_exit_2(tmp_path, capsys):
    assert cal.main(["--fake", "--dataset", str(tmp_path / "nope"),
                     "--out", str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()


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


@pytest.mark.slow
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
                     "--points", "12", "--waves", "0", "--focus-points", "0",
                     "--rerun-replicates", "2", "--steps", "150", "--workers", "1"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["base_config"] == {"rolling_friction": 0.3, "static_friction": 0.5,
                                      "frame": "auto"}
    assert summary["bounds"]["amplitude_m"] == list(cal.APPARATUS["amplitude_m"])
    prof = tmp_path / "profile.json"
    assert ai.main(["--cal", str(out), "--profile", str(prof)]) == 0
    p = json.loads(prof.read_text())
    assert set(p["free"]) == {"amplitude_m", "restitution"}
    assert set(p["config"]) == {"amplitude_m", "restitution", "rolling_friction",
                                "static_friction", "frame"}
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


def test_cli_refuses_a_dataset_too_small_for_the_parameters(tmp_path, capsys):
    """One condition (v_mean and f_col) for four parameters: one clear error before any run,
    naming what to add; nothing written."""
    import shutil
    d = tmp_path / "one"
    shutil.copytree(PAPER_TABLE3_DIR, d)
    for f in ("conditions.csv", "summary.csv"):
        lines = (d / f).read_text().splitlines()
        (d / f).write_text("\n".join(lines[:2]) + "\n")
    assert cal.main(["--fake", "--dataset", str(d), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "degrees of freedom" in err and "more conditions" in err
    assert not (tmp_path / "out").exists()


def test_cli_refuses_a_ball_larger_than_the_jar(tmp_path, capsys):
    """A condition whose ball cannot move in the jar: one error naming the row, before any
    run; nothing written."""
    import shutil
    d = tmp_path / "big"
    shutil.copytree(PAPER_TABLE3_DIR, d)
    c = pd.read_csv(d / "conditions.csv")
    c.loc[1, "ball_diameter_mm"] = 30.0
    c.to_csv(d / "conditions.csv", index=False)
    assert cal.main(["--fake", "--dataset", str(d), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "row 2 (line 3), column 'ball_diameter_mm'" in err and "does not fit" in err
    assert not (tmp_path / "out").exists()


def test_the_calibration_asks_for_the_loops_runs():
    """One model: on the same dataset the calibration's wave 0 (its design, seeds and run
    configs: the frame included) is the loop's, run id for run id - so the runs the loop
    committed serve the calibration."""
    from analysis import loop
    from analysis.measurements import load_dataset
    from analysis.twin_runs import TwinRuns
    ds = load_dataset(PAPER_TABLE3_DIR)
    lbase = loop.run_settings([], frame="auto")
    cbase = cal.base_config_of(None, [], cal.CALIBRATED)
    assert lbase == cbase
    ids = []
    for settings, base in ((loop.LoopSettings(), lbase), (cal.calibration_settings(), cbase)):
        state = loop.read_stage(ds, settings, base_config=base, track=False,
                                log=lambda m: None)
        runs = loop.wave0_runs(state)
        ids.append(TwinRuns(base_config=base, progress=False)._ids(runs)[1])
    assert ids[0] == ids[1] and len(ids[0]) == (24 + 3) * 8
