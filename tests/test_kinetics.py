"""Kinetics: energy, OLS line with bands, regime boundaries, prediction, CLI."""
import json

import numpy as np
import pandas as pd
import pytest

from analysis import kinetics as kin


def test_ball_mass_and_energy_analytic():
    m = kin.ball_mass_kg(0.020)
    assert np.isclose(m, 7800 * np.pi / 6 * 0.020 ** 3)
    assert np.isclose(kin.kinetic_energy_j(0.020, 2.0), 0.5 * m * 4.0)
    e = kin.cumulative_energy_j(0.1, 60.0, np.array([0.0, 60.0, 120.0]))
    assert np.allclose(e, [0.0, 360.0, 720.0])


@pytest.mark.parametrize("call", [
    lambda: kin.ball_mass_kg(-0.01), lambda: kin.kinetic_energy_j(0.02, np.nan),
    lambda: kin.cumulative_energy_j(0.1, 50.0, -1.0)])
def test_energy_bad_input(call):
    with pytest.raises(kin.KineticsInputError):
        call()


def test_table3_inputs_interpolation():
    t = kin.table3_energy_inputs(ball_diameters_mm=(17.5, 20.0, 20.6))
    for f, g in t.groupby("frequency_hz"):
        v = g.set_index(np.round(g["ball_diameter_m"] * 1e3, 3))["v_mean_m_s"]
        assert min(v[17.5], v[20.6]) <= v[20.0] <= max(v[17.5], v[20.6])
        assert np.allclose(g["f_col_hz"], 2 * f)
    assert (t["measured"] == ~np.isclose(t["ball_diameter_m"], 0.020)).all()
    assert t.loc[~t["measured"], "source"].str.contains("NOT twin").all()


def test_twin_table_averages_replicates_and_rejects_bad(tmp_path):
    p = tmp_path / "twin.csv"
    pd.DataFrame({"frequency_hz": [25, 25, 30], "ball_diameter_m": [0.02, 0.02, 0.02],
                  "v_mean_m_s": [2.0, 2.2, 2.5], "f_col_hz": [50, 50, 60]}).to_csv(p, index=False)
    t = kin.load_twin_energy_table(p)
    assert len(t) == 2 and np.isclose(t.iloc[0]["v_mean_m_s"], 2.1) and t.iloc[0]["n_runs"] == 2
    pd.DataFrame({"frequency_hz": [25, -1], "ball_diameter_m": [0.02, 0.02],
                  "v_mean_m_s": [2.0, 2.2], "f_col_hz": [50, 50]}).to_csv(p, index=False)
    with pytest.raises(kin.KineticsInputError, match="row 3, column 'frequency_hz'"):
        kin.load_twin_energy_table(p)
    pd.DataFrame({"frequency_hz": [25], "v_mean_m_s": [2.0], "f_col_hz": [50]}).to_csv(p, index=False)
    with pytest.raises(kin.KineticsInputError, match="ball_diameter_m"):
        kin.load_twin_energy_table(p)


def test_line_fit_exact_and_against_numpy():
    e = np.linspace(500, 4500, 12)
    x = 9.49 * e / 1e3 - 3.03
    fit = kin.fit_powder_line(e, x)
    assert np.isclose(fit.params["a_pct_per_kj"], 9.49) and np.isclose(fit.params["b_pct"], -3.03)
    rng = np.random.default_rng(0)
    xn = x + rng.normal(0, 2, e.size)
    fit = kin.fit_powder_line(e, xn)
    slope, icpt = np.polyfit(e / 1e3, xn, 1)
    assert np.isclose(fit.params["a_pct_per_kj"], slope) and np.isclose(fit.params["b_pct"], icpt)
    assert np.allclose(fit.residuals, xn - (slope * e / 1e3 + icpt))
    p = fit.predict(np.array([500.0, e.mean(), 4500.0]))
    width_ci = p["ci_hi"] - p["ci_lo"]
    assert (p["pi_hi"] - p["pi_lo"] > width_ci).all()
    assert width_ci[1] < width_ci[0] and width_ci[1] < width_ci[2]   # narrowest at mean E
    df = fit.to_frame()
    assert list(df["param"]) == ["a_pct_per_kj", "b_pct"] and (df["stderr"] > 0).all()


def test_line_fit_bad_input():
    with pytest.raises(kin.KineticsInputError, match=">= 3"):
        kin.fit_powder_line([1.0, 2.0], [1.0, 2.0])
    with pytest.raises(kin.KineticsInputError):
        kin.fit_powder_line([1.0, 2.0, np.nan], [1.0, 2.0, 3.0])


def _piecewise(e, e1=4593.0, e2=7126.0, a=9.49, b=-3.03):
    x1 = a * e1 / 1e3 + b
    return np.where(e < e1, a * e / 1e3 + b,
                    np.where(e < e2, x1 + (100 - x1) * (e - e1) / (e2 - e1), 100.0))


def test_boundaries_noise_free_continuous_and_candidates():
    e = np.linspace(700, 9500, 30)
    x = _piecewise(e)
    b = kin.find_boundaries(e, x, method="continuous", n_boot=0)
    assert abs(b.powder_wax_j / 4593 - 1) < 0.005 and abs(b.wax_complete_j / 7126 - 1) < 0.005
    assert b.sse < 1e-3          # exact model; residual only from the finite knot grid
    c = kin.find_boundaries(e, x, method="candidates", n_boot=0)
    step = e[1] - e[0]
    # the paper's method places each boundary in a gap between samples: within one spacing
    assert abs(c.powder_wax_j - 4593) <= step and abs(c.wax_complete_j - 7126) <= step


def test_boundary_bootstrap_interval_contains_truth_with_noise():
    rng = np.random.default_rng(5)
    e = np.repeat(np.linspace(700, 9500, 24), 2)
    x = np.clip(_piecewise(e) + rng.normal(0, 2.0, e.size), 0, 100)
    b = kin.find_boundaries(e, x, method="continuous", n_boot=100, random_state=1)
    assert b.boot.shape == (100, 2)
    assert b.ci.loc["powder_wax_j", "lower"] <= 4593 <= b.ci.loc["powder_wax_j", "upper"]
    assert b.ci.loc["wax_complete_j", "lower"] <= 7126 <= b.ci.loc["wax_complete_j", "upper"]
    assert (b.stderr > 0).all()


def test_boundaries_from_phase_gap_and_logistic():
    e = np.array([1000, 2000, 3000, 4000, 5000, 6000, 7000, 8000.0])
    ph = ["powder"] * 4 + ["wax"] * 2 + ["complete"] * 2
    b = kin.boundaries_from_phase(e, ph)
    assert b.powder_wax_j == 4500 and b.wax_complete_j == 6500
    assert b.ci.loc["powder_wax_j", "lower"] == 4000 and b.ci.loc["powder_wax_j", "upper"] == 5000
    ph2 = ["powder", "powder", "powder", "wax", "powder", "wax", "complete", "complete"]
    b2 = kin.boundaries_from_phase(e, ph2)    # overlapping labels -> logistic 50 % point
    assert 3000 < b2.powder_wax_j < 6000
    assert b2.ci.loc["powder_wax_j", "lower"] < b2.powder_wax_j < b2.ci.loc["powder_wax_j", "upper"]


@pytest.fixture(scope="module")
def fit():
    rng = np.random.default_rng(2)
    e = np.linspace(700, 9500, 30)
    x = np.clip(_piecewise(e) + rng.normal(0, 1.5, e.size), 0, 100)
    ph = np.where(e < 4593, "powder", np.where(e < 7126, "wax", "complete"))
    return kin.fit_kinetics(e, x, phase=ph, n_boot=30, random_state=0)


def test_fit_kinetics_result_object(fit):
    assert fit.powder_selection == "phase" and fit.boundaries.method == "phase"
    assert {b.method for b in fit.alternatives} == {"continuous", "candidates"}
    assert set(fit.params.index) >= {"a_pct_per_kj", "b_pct", "powder_wax_j", "wax_complete_j"}
    df = fit.to_frame()
    assert {"powder_line", "boundary_phase", "boundary_continuous"} <= set(df["kind"])


def test_predict_yield_regimes_and_errors(fit, tmp_path):
    e_kin, f_col = 0.0879, 55.0
    t = np.array([0.0, 5.0, 10.0, 15.0, 20.0, 30.0, 40.0])
    p = kin.predict_yield(fit, e_kin, f_col, t)
    assert np.allclose(p["e_tot_j"], e_kin * f_col * t * 60)
    order = {"powder": 0, "wax": 1, "complete": 2}
    assert np.all(np.diff([order[r] for r in p["regime"]]) >= 0)
    assert ((p["yield_pct"] >= 0) & (p["yield_pct"] <= 100)).all()
    assert np.all(np.diff(p["yield_pct"]) >= -1e-9)
    pw = p[p["regime"] == "powder"]
    assert ((pw["pi_lo"] <= pw["ci_lo"]) & (pw["ci_hi"] <= pw["pi_hi"])).all()
    with pytest.raises(kin.KineticsInputError, match=">= 0"):
        kin.predict_yield(fit, e_kin, f_col, [-1.0])
    with pytest.raises(kin.KineticsInputError, match="order"):
        kin.predict_yield(fit, e_kin, f_col, [10.0, 5.0])
    fit.save(tmp_path / "fit.json")
    back = kin.KineticsFit.load(tmp_path / "fit.json")
    pd.testing.assert_frame_equal(kin.predict_yield(back, e_kin, f_col, t), p)


def test_cli_writes_tables_and_figures(tmp_path, capsys):
    out = tmp_path / "kin"
    assert kin.main(["--out", str(out), "--n-boot", "10"]) == 0
    for name in ("powder_line.csv", "boundaries.csv", "kinetics_fit.json", "fig09_ekin.png",
                 "fig10_yield_time.png", "fig11_yield_energy.png"):
        assert (out / name).is_file()
    assert "SYNTHETIC" in json.loads((out / "kinetics_fit.json").read_text())["source"]
    assert kin.main(["--out", str(tmp_path / "x"), "--yields", str(tmp_path / "none")]) == 2
    assert not (tmp_path / "x").exists()
    assert "error" in capsys.readouterr().err
