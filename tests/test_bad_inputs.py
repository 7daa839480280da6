"""Bad inputs to the command-line tools: one clear error line, exit 2, no traceback, no file.

One table, one row per bad input. Each row runs a tool's ``main(argv)`` in-process with every
input and output in pytest's tmp folder (also the working directory) and checks:

* the exit code is 2;
* stderr is exactly one line, starting with the tool's prefix ``analysis.<module>: error:`` and
  naming the offending option / key and value;
* nothing was printed on stdout and no traceback text appears anywhere;
* no file changed: the tmp folder (hashed) and the repository folders the tool could write or
  read as input (results/, geometry/, data/; by size and mtime) are the same before and after.

The twin rows also prove that no YADE process starts: the subprocess launcher and the YADE lookup
are replaced by functions that fail the test, and the runs folder is moved into the tmp folder.

Then the paths that answer instead of refusing: predict's --extrapolate (marked EXTRAPOLATED,
band wider than the single model's), tracking's --force-fps (warns, tracks at the given rate)
and observe's flag for a collision frequency far from 2 f (warns, records, exit 0).
"""
import hashlib
import json
import os
import shutil

import numpy as np
import pandas as pd
import pytest

from analysis import config
from analysis import kinetics as kin
from analysis import observe as obs
from analysis import predict as pr
from analysis import surrogate as sur
from analysis import tracking as trk
from analysis import twin
from analysis import yield_data as yd
from analysis.synthvideo import Camera, bounce_track, render_video

FPS = 2134.0

#: repository folders the tools could write (or read as input); folders that long-running jobs
#: (twin sweeps, the open-world suite) fill while the tests run are left out: the twin's runs
#: folder is redirected into the tmp folder instead
WATCHED = [config.RESULTS_DIR, config.GEOMETRY_DIR, config.DATA_DIR]
BUSY = {"runs", "runs_fake", "open_world", "loop", "studies"}


# --------------------------------------------------------------------------------------------
# inputs, built once in tmp folders
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def artefacts(tmp_path_factory):
    """A surrogate bundle holding lr, rf and gp, trained on the SYNTHETIC 27-run design (20-30 Hz,
    14.3-20.6 mm), and a kinetics fit of the SYNTHETIC yields, saved in a tmp folder."""
    d = tmp_path_factory.mktemp("predict_artefacts")
    table = sur.synthetic_twin_table(v_rel_sd=0.005, f_col_sd_hz=0.2, seed=11)
    bundle = sur.fit_bundle(table, kinds=sur.KINDS,
                            rf_param_grid={"n_estimators": [50], "min_samples_leaf": [1]})
    ds = yd.load_yield_dataset(yd.SYNTHETIC_DATASET_DIR)
    energy = kin.energy_for_conditions(ds.conditions, kin.table3_energy_inputs())
    data = kin.attach_cumulative_energy(ds.yields, energy)
    kfit = kin.fit_kinetics(data["e_tot_j"], data["yield_pct"], phase=data["phase"], n_boot=20,
                            source="SYNTHETIC test")
    kpath = d / "kinetics_fit.json"
    kfit.save(kpath)
    return {"surrogate": bundle.save(d / "surrogate.joblib"), "kinetics": kpath,
            "bundle": bundle, "kfit": kfit}


@pytest.fixture(scope="module")
def films(tmp_path_factory):
    """One short synthetic film at 2134 fps, three ways: with its ``<stem>.json`` sidecar, with a
    dataset's ``video.json``, and alone (the container's rate is all it declares)."""
    d = tmp_path_factory.mktemp("films")
    cam = Camera(width_px=256, height_px=128, m_per_px=4e-4, exposure_s=100e-6, noise_sigma=2.0,
                 flicker=0.0, occluder=False, fps=FPS)
    render_video(bounce_track(30.0, 0.06), d / "side" / "film.mkv", cam, seed=3)
    (d / "dataset").mkdir()
    shutil.copy(d / "side" / "film.mkv", d / "dataset" / "c1.mkv")
    shutil.copy(d / "side" / "film.json", d / "dataset" / "video.json")
    (d / "bare").mkdir()
    shutil.copy(d / "side" / "film.mkv", d / "bare" / "film.mkv")
    return d


@pytest.fixture
def work(tmp_path, monkeypatch, films):
    """The tmp working folder (cwd) with a copy of the films; the twin can start no YADE."""
    shutil.copytree(films, tmp_path / "films")
    monkeypatch.chdir(tmp_path)

    def no_yade(*args, **kwargs):
        raise AssertionError("a YADE process would have started")

    monkeypatch.setenv("YADE", "/nonexistent/yade")
    monkeypatch.setattr(twin, "RUNS_DIR", tmp_path / "runs")
    monkeypatch.setattr(twin, "yade_executable", no_yade)
    monkeypatch.setattr(twin.subprocess, "run", no_yade)
    return tmp_path


def _snapshot(tmp):
    """{path: fingerprint}: sha256 of every file under ``tmp``, (size, mtime) under WATCHED."""
    snap = {}
    for f in sorted(p for p in tmp.rglob("*") if p.is_file()):
        snap[str(f)] = hashlib.sha256(f.read_bytes()).hexdigest()
    for root in WATCHED:
        for here, dirs, files in os.walk(root):
            dirs[:] = [d for d in dirs if d != "__pycache__"
                       and not (here == str(config.RESULTS_DIR) and d in BUSY)]
            for name in files:
                st = os.stat(os.path.join(here, name))
                snap[os.path.join(here, name)] = (st.st_size, st.st_mtime_ns)
    return snap


def _changes(before, after):
    return sorted(set(before) ^ set(after) | {k for k in before.keys() & after.keys()
                                              if before[k] != after[k]})


# --------------------------------------------------------------------------------------------
# the table: (id, module, argv(ctx), words the error line must hold)
# --------------------------------------------------------------------------------------------
def _pred(*extra):
    return lambda c: ["--surrogate", str(c["surrogate"]), "--kinetics", str(c["kinetics"]),
                      *extra]


def _cond(f="25", d="20", t=("10",), *more):
    return _pred("--frequency-hz", f, "--ball-diameter-mm", d, "--time-min", *t, *more)


def _twin(*argv):
    return lambda c: list(argv)


def _film(sub, name, fps, *more):
    return lambda c: [str(c["work"] / "films" / sub / name), "--fps", fps, "--m-per-px", "4e-4",
                      "--out", str(c["work"] / "track.csv"), *more]


ROWS = [
    # predict: physically impossible
    ("predict-ball-larger-than-jar", pr, _cond(d="30"),
     ["--ball-diameter-mm", "30.00 mm", "larger than the jar's inner diameter", "28.00 mm"]),
    ("predict-ball-as-large-as-jar", pr, _cond(d="28"),
     ["--ball-diameter-mm", "as large as the jar's inner diameter", "28.00 mm"]),
    ("predict-negative-frequency", pr, _cond(f="-3"), ["--frequency-hz", "> 0", "got -3"]),
    ("predict-zero-frequency", pr, _cond(f="0"), ["--frequency-hz", "> 0", "got 0"]),
    ("predict-nan-frequency", pr, _cond(f="nan"), ["--frequency-hz", "finite", "nan"]),
    ("predict-zero-ball", pr, _cond(d="0"), ["--ball-diameter-mm", "> 0", "got 0"]),
    ("predict-negative-ball", pr, _cond(d="-20"), ["--ball-diameter-mm", "got -20"]),
    ("predict-nan-ball", pr, _cond(d="nan"), ["--ball-diameter-mm", "nan"]),
    ("predict-negative-time", pr, _cond(t=("-1",)), ["--time-min", ">= 0", "got -1"]),
    ("predict-nan-time", pr, _cond(t=("5", "nan")), ["--time-min", "finite", "nan"]),
    ("predict-times-out-of-order", pr, _cond(t=("30", "5")), ["--time-min", "order"]),
    ("predict-zero-jar-volume", pr, _cond("25", "20", ("10",), "--jar-volume-ml", "0"),
     ["--jar-volume-ml", "> 0", "got 0"]),
    ("predict-negative-jar-volume", pr, _cond("25", "20", ("10",), "--jar-volume-ml", "-25"),
     ["--jar-volume-ml", "got -25"]),
    ("predict-ball-bigger-than-jar-volume", pr,
     _cond("25", "20", ("10",), "--jar-volume-ml", "3"), ["ball volume", "3 mL"]),
    # predict: outside the surrogates' training domain, no --extrapolate
    ("predict-frequency-outside-domain", pr, _cond(f="40"),
     ["frequency 40 Hz", "training domain", "20-30 Hz", "14.3-20.6 mm", "--extrapolate"]),
    ("predict-ball-outside-domain", pr, _cond(d="10"),
     ["ball 10 mm", "training domain", "14.3-20.6 mm", "--extrapolate"]),
    ("predict-low-frequency-outside-domain", pr, _cond(f="12"),
     ["frequency 12 Hz", "20-30 Hz", "--extrapolate"]),
    # twin: impossible run-config values, refused before YADE
    ("twin-negative-frequency", twin, _twin("--set", "frequency_hz=-3"),
     ["frequency_hz", "-3", "lower bound"]),
    ("twin-zero-frequency", twin, _twin("--set", "frequency_hz=0"),
     ["frequency_hz", "positive", "0"]),
    ("twin-nan-frequency", twin, _twin("--set", "frequency_hz=NaN"), ["frequency_hz", "nan"]),
    ("twin-nan-frequency-option", twin, _twin("--frequency-hz", "nan"),
     ["frequency_hz", "finite", "nan"]),
    ("twin-zero-ball", twin, _twin("--set", "ball_diameter_m=0"),
     ["ball_diameter_m", "= 0 m", "lower bound"]),
    ("twin-negative-ball", twin, _twin("--set", "ball_diameter_m=-0.01"),
     ["ball_diameter_m", "-0.01", "lower bound"]),
    ("twin-negative-ball-option", twin, _twin("--ball-diameter-mm", "-5"),
     ["ball_diameter_m", "-0.005"]),
    ("twin-ball-larger-than-jar", twin, _twin("--set", "ball_diameter_m=0.03"),
     ["ball_diameter_m", "0.03", "30.00 mm", "28.00 mm", "mm400_25ml.stl"]),
    ("twin-restitution-above-1", twin, _twin("--set", "restitution=1.5"),
     ["restitution", "1.5", "upper bound"]),
    ("twin-negative-restitution", twin, _twin("--set", "restitution=-0.1"),
     ["restitution", "-0.1", "lower bound"]),
    ("twin-zero-restitution", twin, _twin("--set", "restitution=0"),
     ["restitution", "(0, 1]", "0"]),
    ("twin-unknown-key", twin, _twin("--set", "frequency=25"),
     ["unknown config key", "frequency", "frequency_hz"]),
    ("twin-not-key-value", twin, _twin("--set", "restitution"), ["key=value", "restitution"]),
    # tracking: --fps disagreeing with the file's own rate
    ("tracking-fps-vs-sidecar", trk, _film("side", "film.mkv", "2000"),
     ["fps 2000", "2134 fps", "sidecar film.json", "--force-fps"]),
    ("tracking-fps-vs-dataset-video-json", trk, _film("dataset", "c1.mkv", "3000"),
     ["fps 3000", "2134 fps", "sidecar video.json", "--force-fps"]),
    ("tracking-fps-vs-container", trk, _film("bare", "film.mkv", "2100"),
     ["fps 2100", "2134 fps", "video container", "--force-fps"]),
    ("tracking-nan-fps", trk, _film("side", "film.mkv", "nan"), ["fps", "nan"]),
]


@pytest.mark.parametrize("module, argv, words", [r[1:] for r in ROWS], ids=[r[0] for r in ROWS])
def test_bad_input_is_one_error_line(module, argv, words, work, artefacts, capsys):
    ctx = dict(artefacts, work=work)
    args = argv(ctx)
    before = _snapshot(work)
    rc = module.main(args)
    out, err = capsys.readouterr()
    after = _snapshot(work)
    prefix = "analysis.%s: error: " % module.__name__.rsplit(".", 1)[1]
    lines = err.strip().splitlines()
    assert rc == 2, (rc, out, err)
    assert len(lines) == 1, err
    assert lines[0].startswith(prefix), lines[0]
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert "Traceback" not in out + err
    assert out == ""
    assert _changes(before, after) == []


def test_table_covers_every_tool():
    assert {r[1] for r in ROWS} == {pr, twin, trk}
    assert len({r[0] for r in ROWS}) == len(ROWS)


@pytest.mark.parametrize("module, units", [
    (pr, ["[Hz]", "[mm]", "[min]", "[mL]"]),
    (twin, ["[Hz]", "[mm]"]),
    (trk, ["[1/s]", "[mm]", "[m/px]", "[frames]", "[px]"]),
    (obs, ["[1/s]", "[Hz]", "[kg]"]),
])
def test_help_states_units_and_ends_with_an_example(module, units, capsys):
    with pytest.raises(SystemExit) as stop:
        module.main(["--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    last_paragraph = text.strip().split("\n\n")[-1]
    assert last_paragraph.startswith("example: python -m " + module.__name__ + " ")
    for u in units:
        assert u in text, u


# --------------------------------------------------------------------------------------------
# predict --extrapolate
# --------------------------------------------------------------------------------------------
def _predict_json(argv, capsys):
    rc = pr.main(argv + ["--json"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    return json.loads(out), err


def test_extrapolate_widens_the_band_and_marks_the_answer(artefacts, work, capsys):
    base = _pred()(artefacts)
    inside = ["--frequency-hz", "25", "--ball-diameter-mm", "20", "--time-min", "4", "8"]
    outside = ["--frequency-hz", "36", "--ball-diameter-mm", "20", "--time-min", "4", "8"]
    before = _snapshot(work)
    doc_in, err_in = _predict_json(base + inside, capsys)
    doc_out, err_out = _predict_json(base + outside + ["--extrapolate"], capsys)
    assert _changes(before, _snapshot(work)) == []
    # inside the domain: no marker, no warning
    assert "EXTRAPOLATED" not in doc_in and err_in == ""
    assert not any(r["out_of_domain"] for r in doc_in["rows"])
    # outside: marked, warned once, and every row says so
    assert doc_out["EXTRAPOLATED"] is True
    assert doc_out["extrapolation"].startswith("EXTRAPOLATED: frequency 36 Hz outside")
    assert err_out.startswith("analysis.predict: warning: ") and len(err_out.splitlines()) == 1
    rows = pd.DataFrame(doc_out["rows"])
    assert rows["extrapolated"].all() and rows["out_of_domain"].all()
    # the centre is the chosen model's; the band is the union over lr, rf, gp: wider than the
    # chosen model's own band at the same condition and wider than the in-domain band
    p = pr.Predictor(artefacts["bundle"], artefacts["kfit"], kind="lr")
    alone = p.query(36.0, 0.020, [4.0, 8.0])
    np.testing.assert_allclose(rows["yield_pct"], alone["yield_pct"], rtol=1e-9)
    width = (rows["pi_hi"] - rows["pi_lo"]).to_numpy()
    width_alone = (alone["pi_hi"] - alone["pi_lo"]).to_numpy()
    width_in = np.array([r["pi_hi"] - r["pi_lo"] for r in doc_in["rows"]])
    assert np.all(rows["yield_spread_pct"] > 1.0)
    assert np.all(width > width_alone + 1.0)
    assert np.all(width > width_in + 1.0)
    assert (rows["ci_lo"] <= alone["ci_lo"]).all() and (rows["ci_hi"] >= alone["ci_hi"]).all()
    assert rows["v_mean_spread_m_s"].iloc[0] > 0 and rows["f_col_spread_hz"].iloc[0] > 0


def test_extrapolate_table_output_carries_the_marker(artefacts, work, capsys):
    argv = _cond("36", "20", ("4",), "--extrapolate")(artefacts)
    assert pr.main(argv) == 0
    out, err = capsys.readouterr()
    assert "** EXTRAPOLATED **" in out.splitlines()[0]
    assert any(ln.startswith("EXTRAPOLATED: frequency 36 Hz") for ln in out.splitlines())
    assert "yield_spread_pct" in out and "Traceback" not in out + err


def test_extrapolate_changes_nothing_inside_the_domain(artefacts, work, capsys):
    for extra in ((), ("--json",)):
        argv = _cond("27.5", "17.5", ("0", "5", "15", "30"), *extra)(artefacts)
        assert pr.main(argv) == 0
        plain = capsys.readouterr()
        assert pr.main(argv + ["--extrapolate"]) == 0
        flagged = capsys.readouterr()
        assert flagged.out == plain.out and flagged.err == plain.err == ""


def test_extrapolate_needs_all_three_surrogates(artefacts, work, capsys):
    lonely = sur.fit_bundle(sur.synthetic_twin_table(seed=3), kinds=("lr",))
    path = lonely.save(work / "lr_only.joblib")
    argv = ["--surrogate", str(path), "--kinetics", str(artefacts["kinetics"]),
            "--frequency-hz", "36", "--ball-diameter-mm", "20", "--time-min", "4", "--extrapolate"]
    before = _snapshot(work)
    assert pr.main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1
    assert err.startswith("analysis.predict: error: ") and "rf, gp" in err
    assert _changes(before, _snapshot(work)) == []


# --------------------------------------------------------------------------------------------
# tracking --force-fps
# --------------------------------------------------------------------------------------------
def test_force_fps_warns_and_tracks_at_the_given_rate(work, capsys):
    out_csv = work / "forced.csv"
    rc = trk.main([str(work / "films" / "side" / "film.mkv"), "--fps", "2000", "--force-fps",
                   "--m-per-px", "4e-4", "--out", str(out_csv)])
    out, err = capsys.readouterr()
    assert rc == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("analysis.tracking: warning: ")
    assert "fps 2000" in lines[0] and "2134 fps" in lines[0] and "Traceback" not in err
    t = pd.read_csv(out_csv)["t_s"].to_numpy()
    assert np.allclose(np.diff(t), 1 / 2000.0)


def test_fps_within_one_percent_is_accepted(work, capsys):
    out_csv = work / "near.csv"
    assert trk.main([str(work / "films" / "side" / "film.mkv"), "--fps", "2150",
                     "--m-per-px", "4e-4", "--out", str(out_csv)]) == 0
    assert capsys.readouterr().err == ""
    assert out_csv.is_file()


# --------------------------------------------------------------------------------------------
# observe: f_col far from 2 f is flagged, not refused
# --------------------------------------------------------------------------------------------
def _sawtooth_csv(path, reversal_hz, dur_s=0.4, speed_m_s=2.0):
    """Track CSV of a ball at constant speed reversing ``reversal_hz`` times per second."""
    half = 1.0 / reversal_hz
    t = 0.37e-3 + np.arange(int(dur_s * FPS)) / FPS
    ph = (t / half) % 2
    x = np.where(ph < 1, speed_m_s * half * ph, speed_m_s * half * (2 - ph))
    pd.DataFrame({"t_s": t, "x_m": x, "y_m": 0 * x}).to_csv(path, index=False)
    return path


@pytest.mark.parametrize("reversal_hz, frequency_hz, suspect", [
    (25.0, 30.0, True),    # 0.42 x 2f: half the collisions missing
    (100.0, 30.0, True),   # 1.67 x 2f: twice as many
    (50.0, 25.0, False),   # 2 f
    (40.0, 25.0, False),   # 0.8 x 2f: plausible
])
def test_observe_flags_f_col_far_from_2f(reversal_hz, frequency_hz, suspect, work, capsys):
    track = _sawtooth_csv(work / "track_in.csv", reversal_hz)
    summary = work / "summary.csv"
    rc = obs.main([str(track), "--fps", str(FPS), "--frequency-hz", str(frequency_hz),
                   "--out", str(summary)])
    out, err = capsys.readouterr()
    assert rc == 0
    row = pd.read_csv(summary).iloc[0]
    ratio = row["f_col_hz"] / (2 * frequency_hz)
    assert row["f_col_ratio_2f"] == pytest.approx(ratio)
    assert bool(row["f_col_suspect"]) is suspect
    lo, hi = obs.F_COL_PLAUSIBLE_RATIO
    assert suspect == (not lo <= ratio <= hi)
    if suspect:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("analysis.observe: warning: ")
        assert "x 2f" in lines[0] and f"f = {frequency_hz:g} Hz" in lines[0]
    else:
        assert err == ""
    assert "Traceback" not in out + err
