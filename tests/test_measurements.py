"""Measurement dataset contract: loading, defaults, atomic writing, and every bad-input path."""
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis.config import PAPER_TABLE3_DIR
from analysis.measurements import (DEFAULT_F_COL_SD_HZ, DEFAULT_V_REL_SD, Dataset, DatasetError,
                                   load_dataset, main, measurement_table, write_dataset)


@pytest.fixture
def ds_dir(tmp_path):
    d = tmp_path / "ds"
    shutil.copytree(PAPER_TABLE3_DIR, d)
    return d


def _edit(path, old, new):
    text = Path(path).read_text()
    assert old in text, old
    Path(path).write_text(text.replace(old, new, 1))


def test_paper_table3_loads():
    ds = load_dataset(PAPER_TABLE3_DIR)
    assert ds.name == "paper_table3" and ds.velocity_frame == "lab"
    assert len(ds.conditions) == 8 and len(ds.summary) == 8
    assert ds.conditions["frequency_hz"].dtype == float
    assert "v_mean_dem_paper_m_s" in ds.summary.columns          # unknown column kept
    assert set(ds.missing_sd) == {"v_mean_sd_m_s", "f_col_sd_hz"}
    assert len(ds.missing_sd["v_mean_sd_m_s"]) == 8
    assert ds.condition_label("f22.5_d20.6") == "20.6 mm ball at 22.5 Hz"
    # f_col = 2 f at all eight conditions (the paper's statement)
    m = ds.summary.merge(ds.conditions, on="condition_id")
    assert np.allclose(m["f_col_hz"], 2 * m["frequency_hz"])


def test_measurement_table_defaults():
    ds = load_dataset(PAPER_TABLE3_DIR)
    t = measurement_table(ds)
    assert t.shape == (16, 5)
    v = t.loc[t["observable"] == "v_mean_m_s"]
    assert np.allclose(v["sd"], DEFAULT_V_REL_SD * v["value"])
    assert np.allclose(t.loc[t["observable"] == "f_col_hz", "sd"], DEFAULT_F_COL_SD_HZ)
    assert t["sd_default"].all()
    t2 = measurement_table(ds, v_rel_sd=0.03, f_col_sd_hz=2.0)
    assert np.allclose(t2.loc[t2["observable"] == "f_col_hz", "sd"], 2.0)
    assert np.allclose(t2.loc[t2["observable"] == "v_mean_m_s", "sd"], 2 * v["sd"].to_numpy())


def test_given_sd_is_used(ds_dir):
    _edit(ds_dir / "summary.csv", "f30_d17.5,2.57,,60,,", "f30_d17.5,2.57,0.05,60,0.5,")
    ds = load_dataset(ds_dir)
    t = measurement_table(ds).set_index(["condition_id", "observable"])
    assert t.loc[("f30_d17.5", "v_mean_m_s"), "sd"] == 0.05
    assert t.loc[("f30_d17.5", "f_col_hz"), "sd"] == 0.5
    assert not t.loc[("f30_d17.5", "v_mean_m_s"), "sd_default"]
    assert "f30_d17.5" not in ds.missing_sd["v_mean_sd_m_s"]


def _full_dataset(tmp_path):
    ds = load_dataset(PAPER_TABLE3_DIR)
    t = np.arange(200) / 2134.0
    ds.tracks = {"f25_d20.6": pd.DataFrame({"t_s": t, "x_m": 0.01 * np.sin(2 * np.pi * 25 * t),
                                            "y_m": np.zeros_like(t)})}
    vid = tmp_path / "clip.avi"
    vid.write_bytes(b"not really a video")
    ds.video = {"fps": 2134.0, "ball_diameter_px": 70.0}
    ds.video_files = {"f25_d20.6": vid}
    ds.yields = pd.DataFrame({"condition_id": ["f25_d20.6"] * 3, "time_min": [5.0, 10.0, 15.0],
                              "yield_pct": [10.0, 20.0, 31.0], "phase": ["powder"] * 3})
    return ds


def test_yield_times_of_lists_each_conditions_times_in_file_order(tmp_path):
    from analysis.measurements import yield_times_of
    ds = load_dataset(PAPER_TABLE3_DIR)
    assert yield_times_of(ds) == {}                               # no yields.csv
    ds.yields = pd.DataFrame({"condition_id": ["f30_d17.5", "f25_d20.6", "f30_d17.5"],
                              "time_min": [10, 5.0, 2.5], "yield_pct": [20.0, 10.0, 5.0]})
    times = yield_times_of(ds)
    assert times == {"f30_d17.5": [10.0, 2.5], "f25_d20.6": [5.0]}
    assert list(times) == ["f30_d17.5", "f25_d20.6"]
    assert all(isinstance(t, float) for ts in times.values() for t in ts)


def test_write_load_round_trip(tmp_path):
    ds = _full_dataset(tmp_path)
    out = write_dataset(ds, tmp_path / "copy")
    back = load_dataset(out)
    assert back.condition_ids == ds.condition_ids
    assert np.allclose(back.summary["v_mean_m_s"], ds.summary["v_mean_m_s"])
    assert back.missing_sd == ds.missing_sd                      # empty sd stays empty
    assert np.allclose(back.tracks["f25_d20.6"]["x_m"], ds.tracks["f25_d20.6"]["x_m"])
    assert back.video == ds.video and set(back.video_files) == {"f25_d20.6"}
    assert list(back.yields["yield_pct"]) == [10.0, 20.0, 31.0]
    assert list(back.yields["phase"]) == ["powder"] * 3
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_write_is_atomic_and_refuses_overwrite(tmp_path):
    ds = _full_dataset(tmp_path)
    out = write_dataset(ds, tmp_path / "copy")
    with pytest.raises(FileExistsError):
        write_dataset(ds, out)
    bad = _full_dataset(tmp_path)
    bad.conditions = bad.conditions.copy()
    bad.conditions.loc[0, "frequency_hz"] = -30.0
    with pytest.raises(DatasetError, match="negative frequency"):
        write_dataset(bad, out, overwrite=True)
    assert load_dataset(out).conditions["frequency_hz"].iat[0] == 30.0   # old copy intact
    assert not (tmp_path / "never").exists()
    with pytest.raises(DatasetError):
        write_dataset(bad, tmp_path / "never")
    assert not (tmp_path / "never").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    ds.summary = ds.summary.copy()
    ds.summary.loc[0, "v_mean_m_s"] = 9.0
    write_dataset(ds, out, overwrite=True)
    assert load_dataset(out).summary["v_mean_m_s"].iat[0] == 9.0


# file, old text, new text, phrases the error must contain (file, row, column)
BAD = [
    ("summary.csv", "v_mean_m_s,", "v_mean_mm_s,", ["summary.csv", "v_mean_mm_s", "wrong unit"]),
    ("conditions.csv", "frequency_hz", "frequency_rpm", ["conditions.csv", "frequency_rpm",
                                                         "wrong unit"]),
    ("conditions.csv", "frequency_hz", "frequency", ["conditions.csv", "no unit"]),
    ("conditions.csv", ",ball_diameter_mm", ",ball_size", ["conditions.csv", "ball_diameter_mm",
                                                            "missing"]),
    ("summary.csv", ",f_col_sd_hz", ",f_col_sd", ["summary.csv", "f_col_sd_hz", "no unit"]),
    ("summary.csv", "f30_d20.6,2.50,", "f30_d20.6,NaN,", ["summary.csv", "row 2", "v_mean_m_s"]),
    ("summary.csv", "f30_d20.6,2.50,", "f30_d20.6,,", ["summary.csv", "row 2", "v_mean_m_s",
                                                        "empty"]),
    ("summary.csv", "f30_d20.6,2.50,", "f30_d20.6,fast,", ["row 2", "v_mean_m_s", "not a number"]),
    ("conditions.csv", "f25_d17.5,25.0", "f25_d17.5,-25.0", ["conditions.csv", "row 5",
                                                             "frequency_hz", "negative frequency"]),
    ("conditions.csv", "f25_d17.5,25.0,17.5", "f25_d17.5,25.0,0", ["row 5", "ball_diameter_mm"]),
    ("conditions.csv", "f30_d20.6,", "f30_d17.5,", ["conditions.csv", "row 2", "duplicate"]),
    ("summary.csv", "f30_d20.6,", "f30_d17.5,", ["summary.csv", "row 2", "duplicate"]),
    ("summary.csv", "f30_d20.6,", "f31_d20.6,", ["summary.csv", "row 2", "unknown condition_id"]),
    ("summary.csv", "f30_d20.6,2.50,,", "f30_d20.6,2.50,-0.1,", ["row 2", "v_mean_sd_m_s"]),
    ("dataset.json", '"lab"', '"camera"', ["dataset.json", "velocity_frame"]),
    ("dataset.json", '"source"', '"origin"', ["dataset.json", "'source'"]),
    ("dataset.json", "{", "{{", ["dataset.json", "malformed JSON"]),
    ("conditions.csv", ",ball_diameter_mm", ",radius", ["conditions.csv", "ball_diameter_mm",
                                                         "missing"]),
    ("conditions.csv", "1\n", "1,extra\n", ["conditions.csv", "row 1", "malformed CSV"]),
]


@pytest.mark.parametrize("fname,old,new,phrases", BAD, ids=[b[2][:20] for b in BAD])
def test_bad_input_raises_one_clear_error(ds_dir, fname, old, new, phrases):
    _edit(ds_dir / fname, old, new)
    with pytest.raises(DatasetError) as exc:
        load_dataset(ds_dir)
    msg = str(exc.value)
    for p in phrases:
        assert p in msg, (p, msg)
    assert str(ds_dir) in msg


@pytest.mark.parametrize("sep", [";", "\t"])
def test_a_regional_csv_is_named(ds_dir, sep):
    """A spreadsheet's regional CSV (semicolons, decimal commas): one error saying so."""
    f = ds_dir / "summary.csv"
    f.write_text(f.read_text().replace(",", sep))
    with pytest.raises(DatasetError, match=r"summary.csv: malformed CSV \(the header is one "
                                           r"field separated by .*commas as separators"):
        load_dataset(ds_dir)


def test_bad_optional_files(ds_dir):
    (ds_dir / "tracks").mkdir()
    (ds_dir / "tracks" / "f99_d1.csv").write_text("t_s,x_m,y_m\n0,0,0\n0.001,0,0\n")
    with pytest.raises(DatasetError, match=r"tracks/f99_d1.csv.*unknown condition_id"):
        load_dataset(ds_dir)
    (ds_dir / "tracks" / "f99_d1.csv").unlink()
    (ds_dir / "tracks" / "f25_d17.5.csv").write_text("t_s,x_m,y_m\n0,0,0\n0.002,0,0\n0.001,0,0\n")
    with pytest.raises(DatasetError, match=r"f25_d17.5.csv.*row 3.*t_s.*increase"):
        load_dataset(ds_dir)
    (ds_dir / "tracks" / "f25_d17.5.csv").write_text("t_s,x_mm,y_m\n0,0,0\n")
    with pytest.raises(DatasetError, match=r"x_mm.*wrong unit"):
        load_dataset(ds_dir)
    shutil.rmtree(ds_dir / "tracks")
    (ds_dir / "yields.csv").write_text("condition_id,time_min,yield_pct\nf25_d17.5,5,10\n"
                                       "f25_d17.5,10,130\n")
    with pytest.raises(DatasetError, match=r"yields.csv, row 2 \(line 3\), column 'yield_pct'"):
        load_dataset(ds_dir)
    (ds_dir / "yields.csv").write_text("condition_id,time_h,yield_pct\nf25_d17.5,5,10\n")
    with pytest.raises(DatasetError, match=r"time_h.*wrong unit.*time_min"):
        load_dataset(ds_dir)
    (ds_dir / "yields.csv").unlink()
    (ds_dir / "videos").mkdir()
    (ds_dir / "videos" / "f25_d17.5.avi").write_bytes(b"x")
    with pytest.raises(DatasetError, match="video.json"):
        load_dataset(ds_dir)
    (ds_dir / "videos" / "video.json").write_text(json.dumps({"ball_diameter_px": 70}))
    with pytest.raises(DatasetError, match="fps"):
        load_dataset(ds_dir)
    (ds_dir / "videos" / "video.json").write_text(json.dumps({"fps": 2134}))
    with pytest.raises(DatasetError, match="ball_diameter_px"):
        load_dataset(ds_dir)
    (ds_dir / "videos" / "video.json").write_text(json.dumps({"fps": 2134, "m_per_px": 3e-4}))
    assert load_dataset(ds_dir).video["m_per_px"] == 3e-4


def test_video_json_states_the_observation_chain(ds_dir):
    """video.json's optional keys for the observation chain: validated with the file and key
    named, exposed as Dataset.observation_chain, and the effects they pin (observation_pins);
    a video.json without films is allowed (it describes how the dataset's speeds were made)."""
    from analysis.measurements import observation_pins
    vdir = ds_dir / "videos"
    vdir.mkdir()
    base = {"fps": 2134, "ball_diameter_px": 70}

    def write(**extra):
        (vdir / "video.json").write_text(json.dumps(dict(base, **extra)))

    for extra, phrase in [
            ({"exposure_s": -1e-6}, "'exposure_s' must be a number >= 0"),
            ({"exposure_s": "100us"}, "'exposure_s' must be a number >= 0"),
            ({"exposure_s": 100.0}, "longer than the frame interval"),
            ({"smoothing_window_frames": 7.5}, "'smoothing_window_frames' must be a whole"),
            ({"smoothing_window_frames": 0}, "'smoothing_window_frames' must be a whole"),
            ({"smoothing_window_frames": True}, "'smoothing_window_frames' must be a whole"),
            ({"smoothing_polyorder": 2}, "needs 'smoothing_window_frames'"),
            ({"smoothing_window_frames": 7, "smoothing_polyorder": -1}, "'smoothing_polyorder'"),
            ({"smoothing_window_frames": 5, "smoothing_polyorder": 5}, "must be less than"),
            ({"scale_method": "ruler"}, "'scale_method' must be one of 'apparent_diameter'")]:
        write(**extra)
        with pytest.raises(DatasetError, match=r"videos/video.json: .*" + phrase):
            load_dataset(ds_dir)
    write(exposure_s=1 / 2134, smoothing_window_frames=7, smoothing_polyorder=2,
          scale_method="calibration_target", camera="Chronos 1.4")     # unknown key: kept
    ds = load_dataset(ds_dir)
    assert ds.observation_chain == {"fps": 2134, "exposure_s": 1 / 2134,
                                    "smoothing_window_frames": 7, "smoothing_polyorder": 2,
                                    "scale_method": "calibration_target"}
    assert ds.video["camera"] == "Chronos 1.4"
    pins = observation_pins(ds.video)
    assert pins["smoothing_window"]["window_s"] == pytest.approx(0.3 * 7 / 2134)
    assert pins["frame_rate"] == {"frame_interval_s": 0.0, "exposure_s": 0.0}
    assert pins["apparent_scale"] == {"blur_fraction": 0.0}
    import effects
    for name, params in pins.items():                      # every pin is a valid setting
        effects.validate(name, params)
    raw = observation_pins(dict(base, smoothing_window_frames=1, exposure_s=2e-4,
                                scale_method="apparent_diameter"))
    assert raw == {"frame_rate": {"frame_interval_s": 1 / 2134, "exposure_s": 2e-4},
                   "smoothing_window": {"window_s": 0.0}}
    assert observation_pins(dict(base, smoothing_window_frames=9, smoothing_polyorder=1)) \
        ["smoothing_window"] == {"window_s": 9 / 2134}
    assert observation_pins(dict(base, smoothing_window_frames=9)) == {}
    assert observation_pins(None) == {} and load_dataset(PAPER_TABLE3_DIR).observation_chain == {}


def test_missing_files(tmp_path, ds_dir):
    with pytest.raises(DatasetError, match="not found"):
        load_dataset(tmp_path / "nope")
    (ds_dir / "summary.csv").unlink()
    with pytest.raises(DatasetError, match="summary.csv: file is missing"):
        load_dataset(ds_dir)


def test_cli(ds_dir, capsys):
    assert main([str(PAPER_TABLE3_DIR)]) == 0
    assert "8 conditions" in capsys.readouterr().out
    _edit(ds_dir / "summary.csv", "v_mean_m_s,", "v_mean_mm_s,")
    assert main([str(ds_dir)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "v_mean_mm_s" in err


def test_a_stated_motion_mode_is_one_of_the_twins_or_empty():
    """conditions.csv's optional motion_mode: the twin's names or empty (not stated); any other
    word is one error naming the row, the column and the names allowed."""
    from analysis.measurements import DatasetError, validate_conditions_table
    from yade_scripts.twin_modes import MOTION_MODES
    df = pd.DataFrame({"condition_id": ["a", "b", "c"], "frequency_hz": ["25", "30", "22"],
                       "ball_diameter_mm": ["17.5", "20.6", "17.5"],
                       "motion_mode": ["end_to_end", "", "chatter"]})
    out = validate_conditions_table(df)
    assert list(out["motion_mode"]) == ["end_to_end", "", "chatter"]
    df.loc[1, "motion_mode"] = "bouncing"
    with pytest.raises(DatasetError) as e:
        validate_conditions_table(df)
    msg = str(e.value)
    assert "row 2 (line 3), column 'motion_mode'" in msg and "'bouncing'" in msg, msg
    assert all(m in msg for m in MOTION_MODES)


def test_a_folder_where_a_file_belongs_is_one_error(ds_dir):
    """A file of the dataset that is a folder (or a folder that is a file) is named, never a
    traceback."""
    for rel, phrase in (("summary.csv", "summary.csv: is a folder"),
                        ("dataset.json", "dataset.json: is a folder")):
        keep = (ds_dir / rel).read_bytes()
        (ds_dir / rel).unlink()
        (ds_dir / rel).mkdir()
        with pytest.raises(DatasetError, match=phrase):
            load_dataset(ds_dir)
        (ds_dir / rel).rmdir()
        (ds_dir / rel).write_bytes(keep)
    (ds_dir / "tracks").write_text("x")
    with pytest.raises(DatasetError, match="tracks: is a file"):
        load_dataset(ds_dir)
    (ds_dir / "tracks").unlink()
    (ds_dir / "tracks").mkdir()
    (ds_dir / "tracks" / "f25_d17.5.csv").mkdir()
    with pytest.raises(DatasetError, match="f25_d17.5.csv: is a folder"):
        load_dataset(ds_dir)
    with pytest.raises(DatasetError, match="is a file; give the dataset's folder"):
        load_dataset(ds_dir / "summary.csv")


def test_a_misspelt_key_of_dataset_json_is_refused_other_keys_are_kept(ds_dir):
    """'synthetc' would drop the SYNTHETIC mark without a word: refused, naming the key it
    resembles; a key unlike any the project reads is kept and ignored."""
    meta = json.loads((ds_dir / "dataset.json").read_text())
    (ds_dir / "dataset.json").write_text(json.dumps(dict(meta, synthetc=True)))
    with pytest.raises(DatasetError, match="unknown key 'synthetc' - did you mean 'synthetic'"):
        load_dataset(ds_dir)
    (ds_dir / "dataset.json").write_text(json.dumps(dict(meta, operator="A. N. Other")))
    assert load_dataset(ds_dir).meta["operator"] == "A. N. Other"


def test_a_condition_without_any_measurement_is_refused(ds_dir):
    """A condition with no summary row, track, film or yield would only cost twin runs."""
    lines = (ds_dir / "summary.csv").read_text().splitlines()
    gone = lines[1].split(",")[0]
    (ds_dir / "summary.csv").write_text("\n".join([lines[0]] + lines[2:]) + "\n")
    with pytest.raises(DatasetError, match="condition %r has no measurement" % gone) as err:
        load_dataset(ds_dir)
    assert str(err.value).count(str(ds_dir)) == 1, err.value     # the folder named once
    (ds_dir / "yields.csv").write_text("condition_id,time_min,yield_pct\n%s,5,10\n" % gone)
    assert gone in set(load_dataset(ds_dir).conditions["condition_id"])   # a yield is one


def test_cli_refuses_what_the_twin_cannot_run(ds_dir, capsys):
    """The check says what the loop would: two conditions of one physics, or two balls."""
    text = (ds_dir / "conditions.csv").read_text()
    header, first = text.splitlines()[:2]
    cols = header.split(",")
    row = dict(zip(cols, first.split(",")))
    twin = dict(row, condition_id="again")
    (ds_dir / "conditions.csv").write_text(text.rstrip("\n") + "\n"
                                           + ",".join(twin[c] for c in cols) + "\n")
    srow = (ds_dir / "summary.csv").read_text().splitlines()
    (ds_dir / "summary.csv").write_text("\n".join(srow + [srow[1].replace(row["condition_id"],
                                                                          "again", 1)]) + "\n")
    assert load_dataset(ds_dir) is not None            # a valid dataset ...
    assert main([str(ds_dir)]) == 2                    # ... the twin cannot run
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "describe the same physics" in err
    n = len(text.splitlines())          # the first data row and its twin, the new last one
    assert "%s, rows 1 and %d (lines 2 and %d)" % (ds_dir / "conditions.csv", n, n + 1) in err


@pytest.mark.parametrize("content, phrase", [
    (b"not a film at all", "OpenCV cannot open it"),
    (b"", "empty file")])
def test_an_unreadable_film_is_refused_before_any_tracking(ds_dir, capsys, content, phrase):
    """A film OpenCV cannot open is one error naming it - from the dataset check and from the
    loop (its dry run too) - before any film is tracked or any run starts; the output folder
    is not made."""
    from analysis import loop
    vdir = ds_dir / "videos"
    vdir.mkdir()
    (vdir / "video.json").write_text(json.dumps({"fps": 2134, "m_per_px": 3e-4}))
    (vdir / "f30_d17.5.mp4").write_bytes(content)
    assert load_dataset(ds_dir).video_files          # the loader only lists the films
    assert main([str(ds_dir)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("analysis.measurements: error: ") and phrase in err
    assert str(vdir / "f30_d17.5.mp4") in err
    out = ds_dir.parent / "out"
    for extra in (["--dry-run"], []):
        rc = loop.main(["--dataset", str(ds_dir), "--out", str(out), "--fake"] + extra)
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert rc == 2 and phrase in err and str(vdir / "f30_d17.5.mp4") in err
        assert not out.exists()
