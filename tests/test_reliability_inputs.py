"""Units checked on every input: one table, one row per case (issue 27, deliverable 3).

Each row prepares one input in pytest's tmp folder - a copy of data/measurements/paper_table3
with a track (25 Hz, 2134 fps, the jar followed), or a track file, a jar STL, a JSON file - and
runs the command as a user would (``python -m analysis.measurements DIR``, ``python -m
analysis.observe TRACK.csv``, ``python -m analysis.twin --set stl_path=...``) in a subprocess,
or, for inputs no command reads on its own (a run config, a film's sidecar), the reader itself.

A refusal row checks: exit code 2, stderr exactly one line starting ``analysis.<module>: error:``
and holding the row's words (file, row / column, the likely unit slip), nothing on stdout, no
traceback. An accepted row checks exit 0 and its documented handling (a byte-order mark read
as no character, gaps read as gaps, a frequency outside 3-35 Hz warned). Every row checks that
no file in the tmp folder changed (sha256 before and after).
"""
import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis import measurements as m
from analysis.config import PAPER_TABLE3_DIR, REPO_ROOT, twin_config

DEFAULT_STL = REPO_ROOT / "geometry" / "mm400_25ml.stl"
TRACK = "tracks/f25_d20.6.csv"
BOM = "\ufeff"


# --------------------------------------------------------------------------------------------
# inputs
# --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def base_track():
    """A clean lab-frame track with the jar (the analytic bounce model, 25 Hz, 0.2 s, e = 0.3:
    end-to-end flight, ten impacts)."""
    from analysis.synthvideo import bounce_track
    return bounce_track(25.0, 0.2, mode="periodic", restitution=0.3).sample(2134.0)


@pytest.fixture
def ds(tmp_path, base_track):
    """paper_table3 plus one track: a valid dataset folder in the tmp folder."""
    d = tmp_path / "ds"
    shutil.copytree(PAPER_TABLE3_DIR, d)
    (d / "tracks").mkdir()
    base_track.to_csv(d / TRACK, index=False)
    return d


def _table(d, name, fn):
    """Rewrite the CSV ``d/name`` as ``fn(frame of str)``."""
    df = pd.read_csv(d / name, dtype=str, keep_default_na=False)
    fn(df)
    df.to_csv(d / name, index=False)


def _track(fn):
    def edit(d):
        df = pd.read_csv(d / TRACK)
        out = fn(df)
        (out if out is not None else df).to_csv(d / TRACK, index=False)
    return edit


def _cell(name, col, row, value):
    """Set the cell of data row ``row`` (from 1) of ``col`` in ``name``."""
    def edit(d):
        def fn(df):
            df.loc[row - 1, col] = value
        _table(d, name, fn)
    return edit


def _column(name, col, value):
    def edit(d):
        def fn(df):
            df[col] = value
        _table(d, name, fn)
    return edit


def _bom(*names):
    def edit(d):
        for n in names:
            p = d / n
            p.write_bytes(BOM.encode() + p.read_bytes())
    return edit


def _text(name, text):
    def edit(d):
        p = d / name
        p.parent.mkdir(exist_ok=True)
        p.write_text(text)
    return edit


def _gaps(rows, as_text=""):
    """Lost frames: x_m, y_m empty (or the text ``as_text``) at these rows."""
    def edit(d):
        def fn(df):
            df.loc[rows, ["x_m", "y_m"]] = as_text
        _table(d, TRACK, fn)
    return edit


def _half_gap(d):
    def fn(df):
        df.loc[40, "x_m"] = ""
    _table(d, TRACK, fn)


def _yields(sd):
    return _text("yields.csv", "condition_id,time_min,yield_pct,yield_sd_pct\n"
                               "f25_d20.6,5,10,1.5\nf25_d20.6,10,20,%s\n" % sd)


def _jitter(df):
    df["x_m"] = np.where(np.arange(len(df)) % 2, 0.1, -0.1)       # span 0.2 m, 427 m/s


DUP_DATASET_JSON = ('{\n  "name": "dup",\n  "description": "",\n  "source": "test",\n'
                    '  "velocity_frame": "lab",\n  "name": "dup2"\n}\n')
DUP_VIDEO_JSON = '{"fps": 2134, "m_per_px": 4e-4, "fps": 1000}\n'


def _stl(factor):
    """The default jar (in mm) with its coordinates multiplied by ``factor``."""
    def make(tmp):
        from geometry.stl_io import read_stl, write_stl
        p = tmp / "jar.stl"
        write_stl(str(p), read_stl(str(DEFAULT_STL)) * factor)
        return p
    return make


# --------------------------------------------------------------------------------------------
# in-process readers (inputs no command reads on its own)
# --------------------------------------------------------------------------------------------
def _call_run_config(tmp):
    p = tmp / "run.json"
    p.write_text('{"frequency_hz": 25.0,\n "restitution": 0.3,\n "frequency_hz": 30.0}\n')
    with pytest.raises(twin_config.ConfigError) as exc:
        twin_config.load_config(str(p))
    return str(exc.value)


def _call_sidecar(tmp):
    from analysis.tracking.video import TrackingError, read_sidecar
    (tmp / "film.mkv").write_bytes(b"")
    (tmp / "film.json").write_text('{"fps": 2134, "fps": 3000}')
    with pytest.raises(TrackingError) as exc:
        read_sidecar(tmp / "film.mkv")
    return str(exc.value)


def _call_stl_stated_um(tmp):
    from geometry.stl_io import measure_jar
    info = measure_jar(str(_stl(1000.0)(tmp)), "um")[1]
    assert info["inner_diameter_m"] == pytest.approx(0.028, rel=1e-6)
    return "inner diameter %.1f mm" % (info["inner_diameter_m"] * 1e3)


def _call_dataset_gaps_flights(tmp, base_track):
    from analysis.flights import dataset_flights
    d = tmp / "gaps"
    shutil.copytree(PAPER_TABLE3_DIR, d)
    (d / "tracks").mkdir()
    tr = base_track.copy()
    tr.loc[[30, 31, 200], ["x_m", "y_m"]] = np.nan
    tr.loc[[120], "jar_x_m"] = np.nan
    tr.to_csv(d / TRACK, index=False)
    clean = d.parent / "clean"
    shutil.copytree(d, clean)
    base_track.to_csv(clean / TRACK, index=False)
    got = dataset_flights(m.load_dataset(d)).set_index("observable")["value"]
    ref = dataset_flights(m.load_dataset(clean)).set_index("observable")["value"]
    assert got["jar_amplitude_m"] == pytest.approx(ref["jar_amplitude_m"], rel=1e-3)
    assert got["e_app"] == pytest.approx(ref["e_app"], abs=0.01)
    return "impact observables from a track with gaps: %d" % len(got)


# --------------------------------------------------------------------------------------------
# the table: (id, tool, edit or maker, rc, words on stderr, words on stdout)
#   tool 'measurements': edit(ds); argv DIR
#   tool 'observe': edit(ds) then the dataset's track; argv TRACK --frequency-hz 25
#   tool 'twin': maker(tmp) -> STL path; argv --set stl_path=P [stl_units=U]
#   tool 'call': fn(tmp) -> text that must hold the words
# --------------------------------------------------------------------------------------------
ROWS = [
    # tracks: speed, stroke and jar amplitude implausible for metres
    ("track-positions-in-mm", "measurements", _track(lambda t: t.assign(
        x_m=t.x_m * 1e3, y_m=t.y_m * 1e3)), 2,
     [TRACK, "column 'x_m'", "more than 0.5 m", "in mm?"], []),
    ("track-speed-implausible", "measurements", _track(_jitter), 2,
     [TRACK, "column 'x_m'", "mean speed", "more than 20 m/s", "mm or cm"], []),
    ("track-time-in-ms", "measurements", _track(lambda t: t.assign(t_s=t.t_s * 1e3)), 2,
     [TRACK, "column 't_s'", "frame rate", "t_s in ms?"], []),
    ("track-jar-in-mm", "measurements", _track(lambda t: t.assign(jar_x_m=t.jar_x_m * 1e3)), 2,
     [TRACK, "column 'jar_x_m'", "more than 0.05 m", "jar_x in mm?"], []),
    ("track-jar-barely-moves", "measurements", _track(lambda t: t.assign(
        jar_x_m=t.jar_x_m * 1e-3)), 2, [TRACK, "column 'jar_x_m'", "less than 0.001 m"], []),
    # stated strokes and ball diameters
    ("stroke-in-metres", "measurements", _column("conditions.csv", "amplitude_mm", "0.013"), 2,
     ["conditions.csv", "row 1", "'amplitude_mm'", "0.013", "less than 1", "13 mm"], []),
    ("stroke-in-um", "measurements", _column("conditions.csv", "amplitude_mm", "13500"), 2,
     ["conditions.csv", "row 1", "'amplitude_mm'", "more than 50", "um?"], []),
    ("ball-diameter-in-metres", "measurements",
     _cell("conditions.csv", "ball_diameter_mm", 3, "0.0175"), 2,
     ["conditions.csv", "row 3", "'ball_diameter_mm'", "metres in the mm column", "17.5 mm"], []),
    # summary: v_mean 0, zero and negative sds
    ("v-mean-zero", "measurements", _cell("summary.csv", "v_mean_m_s", 1, "0"), 2,
     ["summary.csv", "row 1", "'v_mean_m_s'", "implausible", "written as 0"], []),
    ("v-mean-sd-zero", "measurements", _cell("summary.csv", "v_mean_sd_m_s", 2, "0"), 2,
     ["summary.csv", "row 2", "'v_mean_sd_m_s'", "sd 0", "leave the cell empty"], []),
    ("f-col-sd-zero", "measurements", _cell("summary.csv", "f_col_sd_hz", 4, "0.0"), 2,
     ["summary.csv", "row 4", "'f_col_sd_hz'", "sd 0"], []),
    ("v-mean-sd-negative", "measurements", _cell("summary.csv", "v_mean_sd_m_s", 2, "-0.05"), 2,
     ["summary.csv", "row 2", "'v_mean_sd_m_s'", ">= 0", "never negative"], []),
    ("f-col-sd-negative", "measurements", _cell("summary.csv", "f_col_sd_hz", 3, "-1"), 2,
     ["summary.csv", "row 3", "'f_col_sd_hz'", "never negative"], []),
    ("yield-sd-zero", "measurements", _yields("0"), 2,
     ["yields.csv", "row 2", "'yield_sd_pct'", "sd 0"], []),
    # frequencies: refused above the twin's bound, warned outside the tested 3-35 Hz
    ("frequency-above-bound", "measurements", _cell("conditions.csv", "frequency_hz", 1, "75"), 2,
     ["conditions.csv", "row 1", "'frequency_hz'", "more than 60", "rpm"], []),
    ("frequency-60-warned", "measurements", _cell("conditions.csv", "frequency_hz", 1, "60"), 0,
     ["analysis.measurements: warning:", "row 1", "'frequency_hz'", "60 Hz",
      "tested range 3-35 Hz"], ["8 conditions"]),
    ("frequency-2-warned", "measurements", _cell("conditions.csv", "frequency_hz", 2, "2"), 0,
     ["analysis.measurements: warning:", "row 2", "2 Hz", "tested range 3-35 Hz"],
     ["8 conditions"]),
    ("frequency-5-in-range", "measurements", _cell("conditions.csv", "frequency_hz", 1, "5"), 0,
     [], ["8 conditions"]),
    # byte-order marks
    ("bom-conditions-summary", "measurements", _bom("conditions.csv", "summary.csv"), 0, [],
     ["8 conditions, 8 summary rows, 1 tracks"]),
    ("bom-json-and-track", "measurements", _bom("dataset.json", TRACK), 0, [],
     ["paper_table3: 8 conditions", "1 tracks"]),
    # track gaps: the documented way (empty x_m, y_m) accepted, the wrong ways refused
    ("track-gaps-empty-cells", "measurements", _gaps([20, 21, 22, 300]), 0, [], ["1 tracks"]),
    ("track-gaps-nan-text", "measurements", _gaps([20, 300], "NaN"), 0, [], ["1 tracks"]),
    ("track-half-gap", "measurements", _half_gap, 2,
     [TRACK, "row 41", "'x_m'", "empty while y_m is not", "leaves both x_m and y_m empty"], []),
    ("track-skipped-rows", "measurements", _track(lambda t: t.drop(index=[50, 51, 52])), 2,
     [TRACK, "'t_s'", "not uniformly spaced", "not a skipped row"], []),
    ("track-too-many-gaps", "measurements", _gaps(list(range(10, 150))), 2,
     [TRACK, "% of the frames are gaps", "at most 20 %"], []),
    # duplicate JSON keys
    ("duplicate-key-dataset-json", "measurements", _text("dataset.json", DUP_DATASET_JSON), 2,
     ["dataset.json", "key 'name' appears twice", "lines 2, 6"], []),
    ("duplicate-key-video-json", "measurements", _text("videos/video.json", DUP_VIDEO_JSON), 2,
     ["videos/video.json", "key 'fps' appears twice"], []),
    ("duplicate-key-run-config", "call", _call_run_config, None,
     ["run config", "run.json", "key 'frequency_hz' appears twice", "lines 1, 3"], []),
    ("duplicate-key-film-sidecar", "call", _call_sidecar, None,
     ["film.json", "key 'fps' appears twice"], []),
    # observe reads tracks with the same checks and the same gaps
    ("observe-track-in-mm", "observe", _track(lambda t: t.assign(
        x_m=t.x_m * 1e3, y_m=t.y_m * 1e3)), 2, ["f25_d20.6.csv", "'x_m'", "in mm?"], []),
    ("observe-time-in-ms", "observe", _track(lambda t: t.assign(t_s=t.t_s * 1e3)), 2,
     ["f25_d20.6.csv", "'t_s'", "t_s in ms?"], []),
    ("observe-jar-in-mm", "observe", _track(lambda t: t.assign(jar_x_m=t.jar_x_m * 1e3)), 2,
     ["f25_d20.6.csv", "'jar_x_m'", "jar_x in mm?"], []),
    ("observe-gaps-accepted", "observe", _gaps([20, 21, 22, 300]), 0, [],
     ["gap_fraction", "0.0093"]),
    ("observe-bom-accepted", "observe", _bom(TRACK), 0, [], ["v_mean_m_s", "f_col_hz"]),
    # flights reads its track through observe's checked reader
    ("flights-track-in-mm", "flights", _track(lambda t: t.assign(
        x_m=t.x_m * 1e3, y_m=t.y_m * 1e3)), 2, ["f25_d20.6.csv", "'x_m'", "in mm?"], []),
    ("flights-bom-and-gaps-accepted", "flights", lambda d: (_gaps([20, 21])(d), _bom(TRACK)(d)),
     0, [], ["v_in_m_s"]),
    # the loop's impact observables read a gap track too
    ("flights-gaps-accepted", "call", _call_dataset_gaps_flights, None,
     ["impact observables from a track with gaps: 5"], []),
    # STL extents
    ("stl-in-um-read-auto", "twin", (_stl(1000.0), None), 2,
     ["stl_path", "42.8 m across", "stl_units 'auto'", "set stl_units to 'um'"], []),
    ("stl-in-mm-read-as-m", "twin", (_stl(1.0), "m"), 2,
     ["stl_path", "42.8 m across", "stl_units 'm'", "set stl_units to 'mm'"], []),
    ("stl-in-m-read-as-mm", "twin", (_stl(1e-3), "mm"), 2,
     ["stl_path", "4.28e-05 m across", "set stl_units to 'm'"], []),
    ("stl-in-um-stated", "call", _call_stl_stated_um, None, ["inner diameter 28.0 mm"], []),
]


def _snapshot(root):
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(Path(root).rglob("*")) if p.is_file()}


def _run(argv):
    env = dict(os.environ, YADE="/nonexistent/yade")   # no row may start the twin
    return subprocess.run([sys.executable, "-m", *argv], cwd=str(REPO_ROOT), env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("tool, prep, rc, err_words, out_words", [r[1:] for r in ROWS],
                         ids=[r[0] for r in ROWS])
def test_input(tool, prep, rc, err_words, out_words, ds, tmp_path, base_track):
    if tool == "call":
        args = (tmp_path, base_track) if prep is _call_dataset_gaps_flights else (tmp_path,)
        text = prep(*args)
        for w in err_words:
            assert w in text, (w, text)
        return
    if tool == "twin":
        make, units = prep
        stl = make(tmp_path)
        argv = ["analysis.twin", "--set", "stl_path=%s" % stl] + (
            ["stl_units=%s" % units] if units else [])
    else:
        prep(ds)
        argv = (["analysis.measurements", str(ds)] if tool == "measurements"
                else ["analysis.%s" % tool, str(ds / TRACK), "--frequency-hz", "25"])
    before = _snapshot(tmp_path)
    proc = _run(argv)
    after = _snapshot(tmp_path)
    assert before == after, "a file changed"
    assert "Traceback" not in proc.stdout + proc.stderr, proc.stderr
    assert proc.returncode == rc, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    if rc == 2:
        assert len(lines) == 1, proc.stderr
        assert lines[0].startswith("analysis.%s: error: " % argv[0].split(".")[1]), lines[0]
        assert proc.stdout == ""
    elif not err_words:
        assert proc.stderr == "", proc.stderr
    for w in err_words:
        assert w in proc.stderr, (w, proc.stderr)
    for w in out_words:
        assert w in proc.stdout, (w, proc.stdout)


def test_table_rows_are_unique():
    assert len({r[0] for r in ROWS}) == len(ROWS)


def test_bom_is_no_character_in_a_column_name(ds):
    _bom("conditions.csv", "summary.csv", TRACK)(ds)
    d = m.load_dataset(ds)
    assert list(d.conditions.columns[:3]) == ["condition_id", "frequency_hz", "ball_diameter_mm"]
    assert d.summary.columns[0] == "condition_id" and d.tracks["f25_d20.6"].columns[0] == "t_s"


def test_gaps_load_as_nan_and_round_trip(ds, tmp_path):
    _gaps([20, 21, 300])(ds)
    d = m.load_dataset(ds)
    tr = d.tracks["f25_d20.6"]
    assert np.isnan(tr.loc[[20, 21, 300], ["x_m", "y_m"]].to_numpy()).all()
    assert np.isfinite(tr["t_s"]).all() and np.isfinite(tr.drop(index=[20, 21, 300])["x_m"]).all()
    back = m.load_dataset(m.write_dataset(d, tmp_path / "copy"))
    assert np.isnan(back.tracks["f25_d20.6"].loc[[20, 21, 300], "x_m"]).all()


def test_frequency_warning_lines_in_the_dataset(ds):
    _cell("conditions.csv", "frequency_hz", 1, "40")(ds)
    w = m.load_dataset(ds).warnings
    assert len(w) == 1 and "40 Hz" in w[0] and "row 1" in w[0]


def test_bounds_are_declared_once():
    """The dataset's bounds are the twin's run-config bounds where the twin has one."""
    P = twin_config.PARAMETERS
    assert m.FREQUENCY_MAX_HZ == P["frequency_hz"][2]
    assert m.BALL_DIAMETER_MIN_MM == pytest.approx(1e3 * P["ball_diameter_m"][1])
    assert m.BALL_DIAMETER_MAX_MM == pytest.approx(1e3 * P["ball_diameter_m"][2])
    assert m.AMPLITUDE_MAX_MM == pytest.approx(1e3 * P["amplitude_m"][2])
    assert m.JAR_AMPLITUDE_MIN_M == m.AMPLITUDE_MIN_MM / 1e3
    assert m.PLAUSIBLE["v_mean_m_s"][1] == m.TRACK_SPEED_MAX_M_S


def test_every_committed_dataset_still_loads():
    """The bounds break no valid data: every dataset under data/ and results/ loads."""
    found = sorted(p.parent for root in ("data", "results")
                   for p in (REPO_ROOT / root).rglob("dataset.json"))
    assert any(d == PAPER_TABLE3_DIR for d in found)
    for d in found:
        m.load_dataset(d)


def test_the_loop_prints_the_dataset_warnings_in_the_dry_run(ds, tmp_path):
    """A frequency outside the tested 3-35 Hz: the loop says so after reading the dataset,
    one line per warning, the dry run included (and still plans, exit 0)."""
    _cell("conditions.csv", "frequency_hz", 1, "40")(ds)
    _cell("conditions.csv", "frequency_hz", 2, "2.5")(ds)
    proc = _run(["analysis.loop", "--dataset", str(ds), "--out", str(tmp_path / "lo"),
                 "--dry-run", "--fake"])
    assert proc.returncode == 0, proc.stderr
    warn = [ln for ln in proc.stderr.splitlines() if ln.startswith("analysis.loop: warning: ")]
    assert len(warn) == 2, proc.stderr
    assert "40 Hz" in warn[0] and "row 1" in warn[0] and "2.5 Hz" in warn[1]
    assert "Traceback" not in proc.stderr and not (tmp_path / "lo").exists()
