"""analysis.studies.vf_trend without YADE: the trend estimator against known truth, the speed
definitions on an analytic trajectory, the summaries on a synthetic run table, bad input."""
import math

import numpy as np
import pandas as pd
import pytest

from analysis.studies import vf_trend as vt


# ----------------------------------------------------------------------------- the estimator

def test_trend_hand_example():
    a, b = [100.0, 102.0, 98.0], [95.0, 96.0, 94.0]
    t = vt.trend(a, b)
    la, lb = np.log(a), np.log(b)
    d = lb.mean() - la.mean()
    s = math.sqrt((((la - la.mean()) ** 2).sum() + ((lb - lb.mean()) ** 2).sum()) / 4)
    se = s * math.sqrt(2 / 3)
    assert t["change_pct"] == pytest.approx(100 * math.expm1(d))
    assert t["se_pct"] == pytest.approx(100 * math.exp(d) * se)
    assert t["dof"] == 4 and t["n_low"] == 3 and t["n_high"] == 3
    assert t["lo_pct"] < t["change_pct"] < t["hi_pct"]


def test_trend_without_replicates_has_no_se():
    t = vt.trend([90.0], [85.0])
    assert t["change_pct"] == pytest.approx(100 * (85 / 90 - 1))
    assert math.isnan(t["se_pct"]) and t["dof"] == 0
    assert math.isnan(vt.trend([], [85.0, 86.0])["change_pct"])


@pytest.mark.parametrize("n_low,n_high,sd", [(3, 3, 0.015), (2, 4, 0.03), (5, 5, 0.01)])
def test_trend_coverage_and_se_over_many_draws(n_low, n_high, sd):
    """Seed scatter of known size, true change -5 %: the 95 % interval holds the truth in
    95 % of the draws, the stated se is the sd of the estimates, the estimate is unbiased."""
    rng = np.random.default_rng(26)
    truth = -5.0
    mu_low = math.log(90.0)
    mu_high = mu_low + math.log1p(truth / 100)
    draws = 4000
    est, se, cover = np.empty(draws), np.empty(draws), 0
    for k in range(draws):
        a = np.exp(mu_low + sd * rng.standard_normal(n_low))
        b = np.exp(mu_high + sd * rng.standard_normal(n_high))
        t = vt.trend(a, b)
        est[k], se[k] = t["change_pct"], t["se_pct"]
        cover += t["lo_pct"] <= truth <= t["hi_pct"]
    # binomial sd of the coverage at 4000 draws: 0.34 %
    assert abs(cover / draws - 0.95) < 0.012
    true_se = 100 * (1 + truth / 100) * sd * math.sqrt(1 / n_low + 1 / n_high)
    assert np.std(est) == pytest.approx(true_se, rel=0.06)
    assert math.sqrt(np.mean(se ** 2)) == pytest.approx(true_se, rel=0.06)
    assert abs(np.mean(est) - truth) < 4 * true_se / math.sqrt(draws)


def test_trend_estimator_catches_a_wrong_se():
    """The coverage check can fail: halving the se leaves far fewer than 95 % covered."""
    rng = np.random.default_rng(1)
    hits = 0
    for _ in range(2000):
        a = np.exp(4.5 + 0.02 * rng.standard_normal(3))
        b = np.exp(4.5 + 0.02 * rng.standard_normal(3))
        t = vt.trend(a, b)
        hits += abs(t["change_pct"]) <= 1.96 * t["se_pct"] / 2
    assert hits / 2000 < 0.8


def test_shift_and_lever():
    d, se = vt.shift(-5.0, 0.3, 1.0, 0.4)
    assert d == -6.0 and se == pytest.approx(0.5)
    k, miss = vt.lever_reach(-2.0, -1.0, -4.0, -2.0)
    assert k == pytest.approx(2.0) and miss == pytest.approx(0.0, abs=1e-12)
    k, miss = vt.lever_reach(-2.0, 0.0, 0.0, -3.0)       # orthogonal: cannot help
    assert k == pytest.approx(0.0) and miss == pytest.approx(3.0)
    assert all(math.isnan(x) for x in vt.lever_reach(0.0, 0.0, -1.0, -1.0))


# ------------------------------------------------------------------------ speed definitions

def ping_pong(f=23.0, u=2.0, w=0.0, tau=2e-4, dt=1e-5, record_s=4.0, cyl=None, jar_vx=0.0):
    """A ball flying end to end at +-u along x (two reversals per period 1/f, each a linear
    change of v_x from +-u to -+u over tau, centred on t = k/(2f)), a constant v_z = w, and
    optionally a sideways speed c during cylinder contacts of length g * flight at the middle
    of every flight (cyl = (g, c)). Returns (trajectory, impacts) in the recording contract."""
    t = np.arange(0.0, record_s, dt) + 0.25 * dt
    half = 1.0 / (2 * f)
    k = np.floor(t / half + 0.5)                # nearest reversal
    s = t - k * half                            # time from it
    sign = np.where(k % 2 == 0, 1.0, -1.0)      # after reversal k, v_x = sign * u
    ramp = sign * u * 2 * s / tau if tau > 0 else np.zeros_like(t)
    vx = np.where(np.abs(s) <= tau / 2, ramp, np.where(s > 0, sign * u, -sign * u))
    vy = np.zeros_like(t)
    rows = []
    for j in range(int(record_s / half) + 2):
        rows.append((j * half - tau / 2, j * half + tau / 2, "end_cap"))
    if cyl is not None:
        g, c = cyl
        fl = half - tau
        for j in range(int(record_s / half) + 2):
            mid = j * half + half / 2
            rows.append((mid - g * fl / 2, mid + g * fl / 2, "cylinder"))
            vy[(t >= mid - g * fl / 2) & (t <= mid + g * fl / 2)] = c
    x = np.cumsum(vx) * dt
    traj = pd.DataFrame({"t_s": t, "x_m": x, "y_m": np.cumsum(vy) * dt, "z_m": w * t,
                         "vx_m_s": vx, "vy_m_s": vy, "vz_m_s": np.full_like(t, w),
                         "wx_rad_s": 0.0, "wy_rad_s": 0.0, "wz_rad_s": 0.0,
                         "jar_x_m": jar_vx * t, "jar_vx_m_s": np.full_like(t, jar_vx)})
    imp = pd.DataFrame(rows, columns=["t_start_s", "t_end_s", "where"])
    return traj, imp


def test_speed_definitions_analytic_averages():
    f, u, w, tau, g, c = 23.0, 2.0, 0.3, 4e-4, 0.25, 0.5
    traj, imp = ping_pong(f, u, w, tau, cyl=(g, c))
    got = vt.speed_definitions(traj, imp)
    fc = 2 * f * tau                                        # share of time in end contact
    fly3 = (1 - g) * math.hypot(u, w) + g * math.sqrt(u * u + w * w + c * c)
    cont3 = 0.5 * (math.hypot(u, w) + w * w / u * math.asinh(u / w))
    assert got["vx_all"] == pytest.approx((1 - fc) * u + fc * u / 2, rel=1e-3)
    assert got["3d_all"] == pytest.approx((1 - fc) * fly3 + fc * cont3, rel=1e-3)
    assert got["vx_no_end_contact"] == pytest.approx(u, rel=1e-4)
    assert got["3d_no_end_contact"] == pytest.approx(fly3, rel=1e-3)
    assert got["3d_free_flight"] == pytest.approx(math.hypot(u, w), rel=1e-4)
    for ms in (5, 10):                           # instantaneous samples: the flight speed
        assert got["3d_saved_%dms" % ms] == pytest.approx(fly3, rel=0.03)
    assert got["vx_all"] < got["vx_no_end_contact"]


def test_chord_speed_loses_f_delta():
    """Chords over Delta that contain a reversal are short: mean chord speed u (1 - f Delta)
    for an instantaneous reversal (2 f Delta < 1)."""
    f, u = 23.0, 2.0
    traj, imp = ping_pong(f, u, 0.0, tau=0.0, dt=2e-5, record_s=12.0)
    got = vt.speed_definitions(traj, imp)
    for ms in (5, 10):
        assert got["chord_%dms" % ms] == pytest.approx(u * (1 - f * ms * 1e-3), rel=0.01)


def test_jar_frame_speed():
    traj, imp = ping_pong(23.0, 2.0, 0.0, tau=0.0, jar_vx=3.0, record_s=1.0)
    got = vt.speed_definitions(traj, imp)
    assert got["3d_jar_frame"] == pytest.approx(3.0, rel=1e-3)   # (|2-3| + |-2-3|) / 2
    assert got["3d_all"] == pytest.approx(2.0, rel=1e-9)


def test_in_intervals_overlapping():
    m = vt._in_intervals(np.array([0.0, 1.0, 2.5, 3.5, 5.0, 7.0]),
                         np.array([3.0, 0.5]), np.array([4.0, 3.2]))
    assert m.tolist() == [False, True, True, True, False, False]


# ------------------------------------------------------------------------ the summaries

def synthetic_table(changes, seeds=3, sd=0.01, seed=0):
    """A run table like run_table's: variant -> (change 17.5 %, change 20.6 %)."""
    rng = np.random.default_rng(seed)
    rows = []
    for name, (c17, c20) in changes.items():
        for d, c in ((17.5, c17), (20.6, c20)):
            for f in vt.FREQUENCIES_HZ:
                for s in range(seeds):
                    vf = 85.0 * (1 + c / 100 if f == 30.0 else 1.0) * math.exp(
                        sd * rng.standard_normal())
                    rows.append({"variant": name, "group": vt.VARIANTS[name][0],
                                 "condition_id": "f%g_d%g" % (f, d), "frequency_hz": f,
                                 "ball_diameter_mm": d, "seed": s, "run_id": "x%d" % len(rows),
                                 "status": "ok", "v_mean_m_s": vf * f / 1e3, "f_col_hz": 2 * f,
                                 "motion_mode": "end_to_end", "recording": False,
                                 "vf_mm": vf})
    return pd.DataFrame(rows)


def test_summaries_name_the_variant_that_gives_edem():
    e17, e20 = vt.EDEM_TREND_PCT[17.5], vt.EDEM_TREND_PCT[20.6]
    tab = synthetic_table({"default": (1.0, 1.0), "fillet 10 mm": (e17, e20),
                           "A 12 mm": (1.0 + 0.5 * (e17 - 1), 1.0 + 0.5 * (e20 - 1)),
                           "D 24 mm": (5.0, -8.0)}, sd=0.002)
    tab.loc[(tab["variant"] == "D 24 mm") & (tab["seed"] == 0), "motion_mode"] = "slow"
    t = vt.trend_table(tab, 3)
    v = vt.verdicts(t).set_index("variant")
    assert v.loc["fillet 10 mm", "gives_edem_pair"]
    assert not v.loc["A 12 mm", "gives_edem_pair"]
    assert v.loc["A 12 mm", "lever_scale"] == pytest.approx(2.0, rel=0.1)
    assert v.loc["A 12 mm", "lever_miss_pct_points"] < 1.0
    assert v.loc["D 24 mm", "lever_miss_pct_points"] > 2
    row = t[(t["variant"] == "D 24 mm") & (t["ball_diameter_mm"] == 17.5)].iloc[0]
    assert row["not_end_to_end"] == 2 and row["n_22_5hz"] == 2
    from analysis.report.vf_trend_page import conclusions
    words = " ".join(conclusions(t, vt.verdicts(t), vt.study_info()))
    assert "at once: fillet 10 mm." in words


def test_unfinished_variant_is_marked():
    tab = synthetic_table({"default": (1.0, 1.0), "fillet 10 mm": (-5, -3)})
    tab = tab[~((tab["variant"] == "fillet 10 mm") & (tab["seed"] == 2)
                & (tab["frequency_hz"] == 30.0))]
    v = vt.verdicts(vt.trend_table(tab, 3)).set_index("variant")
    assert v.loc["default", "finished"] and not v.loc["fillet 10 mm", "finished"]


def test_a_ball_out_of_end_to_end_flight_in_every_run_is_finished_without_a_trend():
    """All runs done but none in end-to-end flight for one ball: the variant is finished (a
    rerun would not change it), that ball has no trend, and the conclusion names it."""
    tab = synthetic_table({"default": (1.0, 1.0), "restitution 0.5": (-1.0, 0.5)})
    out = (tab["variant"] == "restitution 0.5") & (tab["ball_diameter_mm"] == 20.6)
    tab.loc[out, "motion_mode"] = "slow"
    t = vt.trend_table(tab, 3)
    v = vt.verdicts(t).set_index("variant")
    assert v.loc["restitution 0.5", "finished"]
    row = t[(t["variant"] == "restitution 0.5") & (t["ball_diameter_mm"] == 20.6)].iloc[0]
    assert not row["has_trend"] and row["not_end_to_end"] == 6
    from analysis.report.vf_trend_page import conclusions
    words = " ".join(conclusions(t, vt.verdicts(t), vt.study_info()))
    assert "restitution 0.5, 20.6 mm ball (6 of 6 runs in another mode)" in words


def test_design_is_valid_and_ordered():
    runs = vt.design(["default", "fillet 13 mm (domed)", "arc, pivot above (c -10 1/m)"], 2)
    assert len(runs) == 3 * 4 * 2
    vt.check_design(runs)
    assert list(dict.fromkeys(runs["variant"]))[0] == "default"
    arc = runs[runs["variant"].str.startswith("arc")]["config"].iloc[0]
    assert arc["frame"] == "lab" and arc["restitution"] == 0.11
    assert runs["config"].iloc[0]["frame"] == "jar"


# ------------------------------------------------------------------------------ bad input

@pytest.fixture
def no_runs(monkeypatch):
    def boom(*a, **k):
        raise AssertionError("a twin run was asked for")
    monkeypatch.setattr(vt, "run_table", boom)


@pytest.mark.parametrize("argv,words", [
    (["--seeds", "1"], "--seeds must be >= 2"),
    (["--workers", "0"], "--workers must be >= 1"),
    (["--variants", "no such variant"], "unknown variant"),
    (["--out", "data/vf"], "outside results"),
    (["--out", "results/runs"], "run cache"),
])
def test_bad_input_one_line_exit_2(no_runs, capsys, argv, words):
    assert vt.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("python -m analysis.studies.vf_trend: error:")
    assert words in err[0]


def test_foreign_folder_is_refused(no_runs, capsys, tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    assert vt.main(["--out", str(tmp_path)]) == 2
    assert "did not write" in capsys.readouterr().err
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_invalid_variant_config_is_refused_before_runs(no_runs, capsys, monkeypatch):
    monkeypatch.setitem(vt.VARIANTS, "fillet 20 mm", ("end shape", {
        "jar_inner_diameter_m": 0.028, "jar_fillet_radius_m": 0.020}))
    assert vt.main(["--variants", "fillet 20 mm", "--out", "results/vf_test_never"]) == 2
    assert "fillet 20 mm" in capsys.readouterr().err


def test_cli_rejects_both_modes(capsys):
    with pytest.raises(SystemExit) as e:
        vt.main(["--runs-only", "--cached-only"])
    assert e.value.code == 2


def test_definitions_by_variant_flags_the_pair():
    """A per-run definitions table whose chord_5ms falls as EDEM's does for one variant."""
    rng = np.random.default_rng(3)
    rows = []
    e = vt.EDEM_TREND_PCT
    for name in ("default", "fillet 10 mm"):
        for d in vt.DIAMETERS_MM:
            for f in vt.FREQUENCIES_HZ:
                for s in range(3):
                    base = 80.0 * math.exp(0.003 * rng.standard_normal())
                    row = {"variant": name, "run_id": "r%d" % len(rows), "frequency_hz": f,
                           "ball_diameter_mm": d}
                    for k in vt.SPEED_DEFINITIONS:
                        row[k] = base
                    if name == "fillet 10 mm" and f == 30.0:
                        row["chord_5ms"] = base * (1 + e[d] / 100)
                    rows.append(row)
    bv = vt.definitions_by_variant(pd.DataFrame(rows)).set_index(["variant", "definition"])
    assert bv.loc[("fillet 10 mm", "chord_5ms"), "gives_edem_pair"]
    assert not bv.loc[("default", "chord_5ms"), "gives_edem_pair"]
    assert not bv.loc[("fillet 10 mm", "3d_all"), "gives_edem_pair"]
    assert bv.loc[("fillet 10 mm", "chord_5ms"), "change_17_5_pct"] == pytest.approx(
        e[17.5], abs=1.0)
    lines = __import__("analysis.report.vf_trend_page", fromlist=["x"]).by_variant_lines(
        bv.reset_index(), e, vt.EDEM_VF_MM, vt.MATCH_POINTS)
    assert any("fillet 10 mm read as chord_5ms" in x for x in lines)
