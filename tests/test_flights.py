"""Impact observables of a track with the jar (analysis.flights), checked on an exact 1-D impact
map: a ball in free flight between the two end walls of a jar that moves x_j = A sin(w t), each
impact reversing the velocity relative to the wall with a known restitution e."""

import math

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import brentq

from analysis.flights import (FLIGHT_OBSERVABLES, FlightError, dataset_flights,
                              flight_observables, main)

FPS = 2134.0


def impact_map_track(e=0.3, amplitude_m=0.0127, frequency_hz=25.0, free_length_m=0.042,
                     record_s=0.5, settle_s=0.6, fps=FPS, e_of_v=None, y_amp_m=0.0):
    """Camera track (t_s, x_m, y_m, jar_x_m) and the true impacts (t_s, end, v_in, v_out,
    phase) of the exact impact map; y is B sin(4 pi f t) (vertical motion at 2f)."""
    w = 2 * math.pi * frequency_hz
    half = free_length_m / 2

    def jar(t):
        return amplitude_m * math.sin(w * t)

    def jar_v(t):
        return amplitude_m * w * math.cos(w * t)

    t0, x0, u = 0.0, 0.0, 0.5          # start mid-jar, slowly moving
    segs, imps = [], []
    t_end = settle_s + record_s + 0.01
    while t0 < t_end:
        # next wall contact: first root of the gap to either wall after t0
        def gap(t, s):
            return s * (x0 + u * (t - t0) - jar(t)) - half
        ts = t0 + np.arange(1, 4000) * 2e-6 * 5
        hit = None
        for k in range(len(ts) - 1):
            for s in (1, -1):
                if gap(ts[k], s) < 0 <= gap(ts[k + 1], s):
                    hit = (brentq(gap, ts[k], ts[k + 1], args=(s,), xtol=1e-14), s)
                    break
            if hit:
                break
        if hit is None:
            raise RuntimeError("no impact found")
        tc, s = hit
        segs.append((t0, x0, u, tc))
        V = jar_v(tc)
        v_in = s * (u - V)
        ee = e if e_of_v is None else e_of_v(v_in)
        u_new = V - ee * (u - V)
        xc = x0 + u * (tc - t0)
        ph = (w * tc + (math.pi if s < 0 else 0.0)) % (2 * math.pi)
        imps.append((tc, s, v_in, -s * (u_new - V), ph))
        t0, x0, u = tc, xc, u_new
    t = settle_s + np.arange(int(record_s * fps)) / fps
    x = np.empty_like(t)
    starts = np.array([sg[0] for sg in segs])
    for i, ti in enumerate(t):
        k = int(np.searchsorted(starts, ti, side="right") - 1)
        ts_, xs_, us_, _ = segs[k]
        x[i] = xs_ + us_ * (ti - ts_)
    jx = amplitude_m * np.sin(w * t)
    y = y_amp_m * np.sin(2 * w * t)
    imp = pd.DataFrame(imps, columns=["t_s", "end", "v_in_m_s", "v_out_m_s", "phase_rad"])
    imp = imp[(imp["t_s"] > t[0]) & (imp["t_s"] < t[-1])]
    return pd.DataFrame({"t_s": t, "x_m": x, "y_m": y, "jar_x_m": jx}), imp


@pytest.fixture(scope="module")
def exact():
    return impact_map_track()


def test_exact_impact_map_is_read_back(exact):
    tr, imp = exact
    res = flight_observables(tr["t_s"], tr["x_m"], tr["y_m"], tr["jar_x_m"], 25.0)
    v = res.values
    assert set(v) == set(FLIGHT_OBSERVABLES)
    assert len(imp) >= 20 and len(res.impacts) >= len(imp) - 2
    assert v["e_app"] == pytest.approx(0.3, abs=0.01)
    assert v["v_in_m_s"] == pytest.approx(imp["v_in_m_s"].median(), rel=0.01)
    z = np.exp(1j * imp["phase_rad"].to_numpy()).mean()
    assert abs(math.remainder(v["impact_phase_rad"] - np.angle(z), 2 * math.pi)) < 0.03
    assert v["jar_amplitude_m"] == pytest.approx(0.0127, rel=1e-6)
    assert v["vy_rms_m_s"] < 1e-3
    # the impact times are found to a fraction of a frame
    got = res.impacts["t_s"].to_numpy()
    for tc in imp["t_s"].to_numpy()[2:-2]:
        assert np.min(np.abs(got - tc)) < 0.2 / FPS


def test_restitution_and_amplitude_move_their_observables():
    lo = flight_observables(*_cols(impact_map_track(e=0.2)[0]), 25.0).values
    hi = flight_observables(*_cols(impact_map_track(e=0.45)[0]), 25.0).values
    assert lo["e_app"] == pytest.approx(0.2, abs=0.01) and hi["e_app"] == pytest.approx(0.45,
                                                                                      abs=0.01)
    big = flight_observables(*_cols(impact_map_track(amplitude_m=0.014)[0]), 25.0).values
    assert big["jar_amplitude_m"] == pytest.approx(0.014, rel=1e-6)


def test_speed_dependent_restitution_shows_in_e_app():
    """1 - e growing like v^(1/5) (the viscoelastic law): e_app is the law at the impact speed."""
    law = lambda v: 0.45 * (1 - 0.3 * v ** 0.2)       # noqa: E731
    tr, imp = impact_map_track(e_of_v=law)
    v = flight_observables(*_cols(tr), 25.0).values
    assert v["e_app"] == pytest.approx(law(v["v_in_m_s"]), abs=0.01)


def test_tracking_noise_and_vertical_motion():
    tr, _ = impact_map_track(y_amp_m=2e-4)
    clean = flight_observables(*_cols(tr), 25.0).values
    # the 7-frame Savitzky-Golay derivative's gain on a sinusoid at 50 Hz: 2/28 sum k sin(k th)/th
    th = 2 * math.pi * 50.0 / FPS
    gain = 2.0 / 28.0 * sum(k * math.sin(k * th) for k in (1, 2, 3)) / th
    true_vy = 2e-4 * 4 * math.pi * 25.0 / math.sqrt(2) * gain
    assert clean["vy_rms_m_s"] == pytest.approx(true_vy, rel=0.005)
    rng = np.random.default_rng(3)
    noisy = tr.copy()
    for c in ("x_m", "y_m", "jar_x_m"):
        noisy[c] = noisy[c] + 5e-6 * rng.standard_normal(len(noisy))
    res = flight_observables(*_cols(noisy), 25.0)
    v = res.values
    assert v["e_app"] == pytest.approx(clean["e_app"], abs=0.01)
    assert v["v_in_m_s"] == pytest.approx(clean["v_in_m_s"], rel=0.01)
    assert v["jar_amplitude_m"] == pytest.approx(0.0127, rel=1e-3)
    # the noise (sqrt(gain) x 5 um x fps ~ 2 mm/s on vy) is taken out of the rms
    assert v["vy_rms_m_s"] == pytest.approx(true_vy, rel=0.03)
    assert all(res.se[k] > 0 for k in FLIGHT_OBSERVABLES)


def test_gaps_leave_the_observables_unchanged(exact):
    """Lost frames (NaN ball or jar positions, a dataset track's empty cells) are gaps: the
    impacts whose fit windows touch one are left out, the rest read as before."""
    tr, _ = exact
    clean = flight_observables(*_cols(tr), 25.0).values
    gappy = tr.copy()
    rows = np.random.default_rng(5).choice(len(tr), size=len(tr) // 50, replace=False)
    gappy.loc[rows, ["x_m", "y_m"]] = np.nan
    gappy.loc[rows[:5] + 1, "jar_x_m"] = np.nan
    v = flight_observables(*_cols(gappy), 25.0).values
    assert v["e_app"] == pytest.approx(clean["e_app"], abs=0.01)
    assert v["v_in_m_s"] == pytest.approx(clean["v_in_m_s"], rel=0.01)
    assert v["jar_amplitude_m"] == pytest.approx(clean["jar_amplitude_m"], rel=1e-6)
    assert v["vy_rms_m_s"] == pytest.approx(clean["vy_rms_m_s"], rel=0.05)


def _cols(tr):
    return tr["t_s"], tr["x_m"], tr["y_m"], tr["jar_x_m"]


def test_bad_tracks_give_one_clear_error(exact):
    tr, _ = exact
    bad = tr.copy()
    bad.loc[10, "t_s"] = np.nan
    with pytest.raises(FlightError, match="t_s has NaN at row 10"):
        flight_observables(*_cols(bad), 25.0)
    lost = tr.copy()
    lost.loc[: int(0.3 * len(tr)), "x_m"] = np.nan                  # 30 % gaps: over the limit
    with pytest.raises(FlightError, match=r"30\.\d % of the frames are gaps"):
        flight_observables(*_cols(lost), 25.0)
    with pytest.raises(FlightError, match="frequency_hz must be > 0"):
        flight_observables(*_cols(tr), -25.0)
    with pytest.raises(FlightError, match="less than two jar cycles"):
        flight_observables(*_cols(tr.iloc[:30]), 25.0)
    still = tr.assign(jar_x_m=0.0)
    with pytest.raises(FlightError, match="does not move"):
        flight_observables(*_cols(still), 25.0)
    rest = tr.assign(x_m=tr["jar_x_m"] - 0.02)       # the ball riding on one end
    with pytest.raises(FlightError):
        flight_observables(*_cols(rest), 25.0)


def _dataset(track, frame="lab"):
    from analysis.measurements import Dataset
    cond = pd.DataFrame({"condition_id": ["f25_d20.6", "f30_d17.5"], "frequency_hz": [25.0, 30.0],
                         "ball_diameter_mm": [20.6, 17.5]})
    summ = pd.DataFrame({"condition_id": cond["condition_id"], "v_mean_m_s": [2.1, 2.6],
                         "v_mean_sd_m_s": [0.03, 0.04], "f_col_hz": [50.0, 60.0],
                         "f_col_sd_hz": [1.0, 1.0]})
    return Dataset(name="t", description="", source="test", velocity_frame=frame,
                   conditions=cond, summary=summ, tracks={"f25_d20.6": track})


def test_dataset_flights_floors_and_frames(exact, tmp_path):
    from analysis.measurements import load_dataset, write_dataset
    tr, _ = exact
    ds = load_dataset(write_dataset(_dataset(tr), tmp_path / "lab"))
    obs = dataset_flights(ds)
    assert list(obs["condition_id"].unique()) == ["f25_d20.6"]      # no track: no rows
    assert list(obs["observable"]) == list(FLIGHT_OBSERVABLES)
    o = obs.set_index("observable")
    # a film's lengths and speeds share its scale error (0.5 %); the ratios and the phase not
    for k in FLIGHT_OBSERVABLES:
        scaled = k in ("v_in_m_s", "jar_amplitude_m", "vy_rms_m_s")
        assert o.loc[k, "shared_sd"] == pytest.approx(0.005 * abs(o.loc[k, "value"]) * scaled)
        assert o.loc[k, "sd"] >= o.loc[k, "shared_sd"]
    assert o.loc["jar_amplitude_m", "sd"] == pytest.approx(0.005 * 0.0127, rel=1e-3)
    assert o.loc["e_app", "sd"] >= 0.005
    jar = tr.assign(x_m=tr["x_m"] - tr["jar_x_m"])
    obs_j = dataset_flights(load_dataset(write_dataset(_dataset(jar, "jar"), tmp_path / "jar")))
    assert np.allclose(obs_j["value"], obs["value"], rtol=1e-9, atol=1e-12)
    # a track without the jar gives nothing; a non-numeric jar_x_m is a dataset error
    assert len(dataset_flights(_dataset(tr.drop(columns="jar_x_m")))) == 0
    from analysis.measurements import DatasetError
    d = tmp_path / "bad"
    write_dataset(_dataset(tr), d)
    f = d / "tracks" / "f25_d20.6.csv"
    lines = f.read_text().splitlines()
    lines[5] = ",".join(lines[5].split(",")[:3] + ["abc"])
    f.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="jar_x_m"):
        load_dataset(d)


def test_cli(exact, tmp_path, capsys):
    tr, _ = exact
    p = tmp_path / "track.csv"
    tr.to_csv(p, index=False)
    assert main([str(p), "--frequency-hz", "25", "--impacts", str(tmp_path / "imp.csv")]) == 0
    assert "e_app" in capsys.readouterr().out
    assert len(pd.read_csv(tmp_path / "imp.csv")) >= 20
    assert main([str(p)]) == 2
    tr.drop(columns="jar_x_m").to_csv(p, index=False)
    assert main([str(p), "--frequency-hz", "25"]) == 2
    assert "jar_x_m" in capsys.readouterr().err


def test_end_stratified_se_matches_the_scatter_between_records():
    """Records whose two ends differ systematically (one end clean, the other with a share of
    slow double hits): the se stated for one record's median v_in, median e and mean phase
    matches the sd of those values over independent records (within 30 %), where the
    pooled-sample formula overstates it."""
    from analysis.flights import _end_bootstrap_se, _median_se
    rng = np.random.default_rng(42)
    vals, ses, pooled = [], [], []
    for _ in range(300):
        ends = np.tile([1, -1], 13)
        n_p = int(np.sum(ends > 0))
        vin = np.where(ends < 0, 3.5 + 0.05 * rng.standard_normal(ends.size),
                       np.where(rng.random(ends.size) < 0.3, rng.uniform(0.5, 3.0, ends.size),
                                3.45 + 0.05 * rng.standard_normal(ends.size)))
        e = np.where(ends < 0, 0.22, 0.235) + 0.015 * rng.standard_normal(ends.size)
        ph = np.where(ends < 0, 2.6, 2.3) + 0.08 * rng.standard_normal(ends.size)
        z = np.exp(1j * ph)
        zm = z.mean()
        se_e, se_v, se_ph = _end_bootstrap_se(ends, e, vin, z, zm)
        vals.append([np.median(e), np.median(vin), np.angle(zm)])
        ses.append([se_e, se_v, se_ph])
        pooled.append([_median_se(e), _median_se(vin)])
        assert n_p == 13
    sd = np.std(vals, axis=0, ddof=1)
    rms = np.sqrt(np.mean(np.square(ses), axis=0))
    ratio = sd / rms
    assert np.all((ratio > 0.7) & (ratio < 1.3)), ratio
    assert np.sqrt(np.mean(np.square(pooled), axis=0))[1] > 1.15 * sd[1]  # the old formula
