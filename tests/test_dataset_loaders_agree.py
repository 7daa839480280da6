"""One contract, two loaders: analysis.measurements.load_dataset and
analysis.yield_data.load_yield_dataset read conditions.csv and yields.csv through the same
parser (analysis.measurements), so they return the same conditions and yields and refuse a
malformed yields.csv with the same error (each in its own row numbering: measurements says
'row 5 (line 6)', yield_data 'row 6', the file line)."""
import csv
import shutil

import numpy as np
import pandas as pd
import pytest

from analysis import measurements as m
from analysis import yield_data as yd
from analysis.config import PAPER_TABLE3_DIR
from analysis.diagnose import observations_from_dataset


@pytest.fixture(scope="module")
def energy():
    return yd.synthetic_energy_inputs(tuple(yd.DEFAULT_SCHEDULE_MIN))


@pytest.fixture
def gen_dir(tmp_path, energy):
    """A dataset folder written by yield_data's generator (with the summary.csv the CLI writes,
    which load_dataset needs)."""
    cond, y, meta = yd.generate_synthetic_yields(energy=energy, seed=5)
    return yd.write_yield_dataset(tmp_path / "gen", cond, y, meta, summary=yd._summary_for(energy))


@pytest.fixture
def table3_dir(tmp_path):
    """paper_table3 with a hand-written yields.csv: mixed-case and missing phase labels, an sd
    column with an empty cell, replicates (equal times) and interleaved conditions."""
    d = tmp_path / "table3"
    shutil.copytree(PAPER_TABLE3_DIR, d)
    (d / "yields.csv").write_text(
        "condition_id,time_min,yield_pct,phase,yield_sd_pct,note\n"
        "f25_d17.5,5,10,Powder,1.5,a\n"
        "f30_d20.6,2.5,5,,2,\n"
        "f25_d17.5,10,20, wax ,,b\n"
        "f25_d17.5,10,22,NA,,\n"
        "f30_d20.6,5,9,complete,3,c\n")
    return d


def _edit_rows(path, fn):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    rows = fn(rows)
    with open(path, "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)


def _set(col, row, value):
    """Edit: data row ``row`` (1 = first row under the header), column ``col`` := value."""
    def fn(rows):
        rows[row][rows[0].index(col)] = value
        return rows
    return fn


def assert_loaders_agree(folder):
    ds = m.load_dataset(folder)
    yds = yd.load_yield_dataset(folder)
    # conditions: same rows, same columns, same validated values of the contract's columns
    assert list(yds.conditions.columns) == list(ds.conditions.columns)
    assert ds.condition_ids == list(yds.conditions["condition_id"])
    for col in m.CONDITIONS_COLUMNS:
        if col in ds.conditions.columns:
            assert list(yds.conditions[col]) == list(ds.conditions[col]), col
    for col in ("frequency_hz", "ball_diameter_mm"):
        assert yds.conditions[col].dtype == ds.conditions[col].dtype == float
    # yields: same samples in the same order
    assert ds.yields is not None
    assert list(yds.yields.columns) == list(ds.yields.columns)
    assert list(yds.yields["condition_id"]) == list(ds.yields["condition_id"])
    for col in ("time_min", "yield_pct", "yield_sd_pct"):
        if col in ds.yields.columns:
            np.testing.assert_array_equal(yds.yields[col].to_numpy(float),
                                          ds.yields[col].to_numpy(float))
    if "phase" in ds.yields.columns:             # yield_data's view: lower case, NA where empty
        expect = [m.phase_label(v) for v in ds.yields["phase"]]
        got = [None if pd.isna(v) else v for v in yds.yields["phase"]]
        assert got == expect
    # other columns: yield_data types them as pandas does, measurements keeps the text
    for col in ds.yields.columns:
        if col not in m.YIELDS_COLUMNS:
            text = ds.yields[col].replace("", np.nan)
            num = pd.to_numeric(text, errors="coerce")
            if num.notna().sum() == text.notna().sum():
                np.testing.assert_array_equal(yds.yields[col].to_numpy(float),
                                              num.to_numpy(float))
    return ds, yds


# ---------------------------------------------------------------------------- same tables
def test_generated_folder_agrees(gen_dir):
    ds, yds = assert_loaders_agree(gen_dir)
    assert yds.synthetic and ds.synthetic
    assert yds.yields["e_tot_j_true"].dtype == float        # generator's extra column, typed
    assert set(yds.yields["phase"].dropna()) <= set(yd.PHASES)


def test_shipped_synthetic_yields_agree():
    assert_loaders_agree(yd.SYNTHETIC_DATASET_DIR)


def test_paper_table3_with_yields_agrees(table3_dir):
    ds, yds = assert_loaders_agree(table3_dir)
    assert [None if pd.isna(v) else v for v in yds.yields["phase"]] == \
        ["powder", None, "wax", None, "complete"]
    assert list(ds.yields["phase"]) == ["Powder", "", "wax ", "NA", "complete"]  # as read
    assert np.isnan(yds.yields["yield_sd_pct"].iat[2]) and yds.yields["yield_sd_pct"].iat[0] == 1.5


def test_paper_table3_conditions_agree_and_yields_are_required_by_yield_data():
    ds = m.load_dataset(PAPER_TABLE3_DIR)
    assert ds.yields is None
    with pytest.raises(yd.YieldDataError, match=r"paper_table3/yields.csv: file is missing"):
        yd.load_yield_dataset(PAPER_TABLE3_DIR)
    raw = m.read_table(PAPER_TABLE3_DIR / "conditions.csv")
    cond = yd.validate_conditions(raw, PAPER_TABLE3_DIR / "conditions.csv")
    for col in ("condition_id", "frequency_hz", "ball_diameter_mm", "n_balls"):
        assert list(cond[col]) == list(ds.conditions[col])


def test_public_validators_accept_pandas_frames(gen_dir):
    """validate_conditions / validate_yields keep their signatures and take frames read by
    pandas (numbers, NaN) as before."""
    cond = yd.validate_conditions(pd.read_csv(gen_dir / "conditions.csv"),
                                  gen_dir / "conditions.csv")
    y = yd.validate_yields(pd.read_csv(gen_dir / "yields.csv"), gen_dir / "yields.csv",
                           cond["condition_id"])
    yds = yd.load_yield_dataset(gen_dir)
    pd.testing.assert_frame_equal(cond, yds.conditions, check_dtype=False)
    pd.testing.assert_frame_equal(y, yds.yields, check_dtype=False)
    with pytest.raises(yd.YieldDataError, match=r"yields.csv, row 3, column 'yield_pct'"):
        yd.validate_yields(pd.read_csv(gen_dir / "yields.csv").assign(
            yield_pct=lambda d: d["yield_pct"].where(d.index != 1, 120.0)),
            gen_dir / "yields.csv", cond["condition_id"])


def test_diagnose_yield_observations_use_the_shared_sd_default(table3_dir):
    ds = m.load_dataset(table3_dir)
    obs = observations_from_dataset(ds, yield_sd_pct=4.0)
    y = obs[obs["observable"].str.startswith("yield_pct@")]
    assert list(y["observable"]) == ["yield_pct@5min", "yield_pct@2.5min", "yield_pct@10min",
                                     "yield_pct@10min", "yield_pct@5min"]
    assert list(y["sd"]) == [1.5, 2.0, 4.0, 4.0, 3.0]          # empty sd cell -> the default
    t = m.yield_table(ds, yield_sd_pct=4.0)
    assert list(t["sd_default"]) == [False, False, True, True, False]
    assert list(t["value"]) == list(y["value"])


# ---------------------------------------------------------------------------- same errors
# edit of yields.csv, location in load_dataset's message, location in load_yield_dataset's,
# words the (shared) rest of the message holds
BAD_YIELDS = [
    (_set("yield_pct", 5, ""), ", row 5 (line 6), column 'yield_pct': ",
     ", row 6, column 'yield_pct': ", ["empty"]),
    (_set("yield_pct", 2, "130"), ", row 2 (line 3), column 'yield_pct': ",
     ", row 3, column 'yield_pct': ", ["130", "outside"]),
    (_set("yield_pct", 3, "lots"), ", row 3 (line 4), column 'yield_pct': ",
     ", row 4, column 'yield_pct': ", ["'lots'", "not a number"]),
    (_set("time_min", 1, "-5"), ", row 1 (line 2), column 'time_min': ",
     ", row 2, column 'time_min': ", ["negative time"]),
    (_set("condition_id", 4, "nope"), ", row 4 (line 5), column 'condition_id': ",
     ", row 5, column 'condition_id': ", ["unknown condition", "nope"]),
    (lambda r: [r[0] + ["yield_sd_pct"]] + [x + ["-1" if i == 2 else "1"]
                                            for i, x in enumerate(r[1:], start=1)],
     ", row 2 (line 3), column 'yield_sd_pct': ", ", row 3, column 'yield_sd_pct': ", [">= 0"]),
    (lambda r: [[c.replace("time_min", "time_h") for c in r[0]]] + r[1:], ": ", ": ",
     ["time_h", "wrong unit", "time_min"]),
    (lambda r: [[c for c in r[0] if c != "yield_pct"]]
     + [x[:2] + x[3:] for x in r[1:]], ": ", ": ", ["required column 'yield_pct' is missing"]),
    (lambda r: r[:3] + [r[3] + ["extra"]] + r[4:], ", row 3 (line 4): ", ", row 4: ",
     ["malformed CSV"]),
    (lambda r: r[:1], ": ", ": ", ["no data rows"]),
]


@pytest.mark.parametrize("edit, where_m, where_y, words", BAD_YIELDS,
                         ids=["empty", "130", "text", "neg_time", "unknown",
                              "neg_sd", "unit", "missing_col", "fields", "no_rows"])
def test_malformed_yields_same_error_both_paths(gen_dir, edit, where_m, where_y, words):
    _edit_rows(gen_dir / "yields.csv", edit)
    with pytest.raises(m.DatasetError) as em:
        m.load_dataset(gen_dir)
    with pytest.raises(yd.YieldDataError) as ey:
        yd.load_yield_dataset(gen_dir)
    assert isinstance(ey.value, m.DatasetError) and isinstance(ey.value, ValueError)
    fname = str(gen_dir / "yields.csv")
    msg_m, msg_y = str(em.value), str(ey.value)
    assert msg_m.startswith(fname + where_m), msg_m
    assert msg_y.startswith(fname + where_y), msg_y
    rest = msg_m[len(fname + where_m):]
    assert rest == msg_y[len(fname + where_y):]
    for w in words:
        assert w in rest, (w, rest)


@pytest.mark.parametrize("edit, where_y, words", [
    (_set("time_min", 2, "99"), ", row 4, column 'time_min': ", ["out of order", "99 then 7.5"]),
    (_set("phase", 1, "slurry"), ", row 2, column 'phase': ", ["slurry", "powder, wax, complete"]),
], ids=["order", "phase"])
def test_yield_tools_are_stricter_than_the_dataset_contract(gen_dir, edit, where_y, words):
    """The dataset contract (docs/dataset_format.md) takes yields.csv rows in any order and keeps
    a phase label as read; the yield-data tools (analysis.yield_data) refuse both."""
    _edit_rows(gen_dir / "yields.csv", edit)
    ds = m.load_dataset(gen_dir)
    assert ds.yields is not None and len(ds.yields)
    with pytest.raises(yd.YieldDataError) as ey:
        yd.load_yield_dataset(gen_dir)
    msg = str(ey.value)
    assert msg.startswith(str(gen_dir / "yields.csv") + where_y), msg
    for w in words:
        assert w in msg, (w, msg)


def test_malformed_conditions_same_error_both_paths(gen_dir):
    _edit_rows(gen_dir / "conditions.csv", _set("frequency_hz", 2, "-27.5"))
    with pytest.raises(m.DatasetError) as em:
        m.load_dataset(gen_dir)
    with pytest.raises(yd.YieldDataError) as ey:
        yd.load_yield_dataset(gen_dir)
    fname = str(gen_dir / "conditions.csv")
    assert str(em.value) == fname + (", row 2 (line 3), column 'frequency_hz': "
                                     "negative frequency -27.5 must be > 0")
    assert str(ey.value) == fname + (", row 3, column 'frequency_hz': "
                                     "negative frequency -27.5 must be > 0")


def test_summary_wide_is_the_one_wide_table_and_names_a_missing_summary_row(tmp_path):
    """demo.measured_table is summary_wide on the loaded dataset; a condition without a
    summary row is one error naming the condition and the folder."""
    import shutil
    from analysis import demo
    from analysis.config import PAPER_TABLE3_DIR
    a = demo.measured_table()
    assert a.equals(m.summary_wide(m.load_dataset(PAPER_TABLE3_DIR)))
    assert (a["ball_diameter_m"] == a["ball_diameter_mm"] / 1000.0).all()
    assert a["v_mean_dem_paper_m_s"].dtype.kind == "f"
    d = tmp_path / "ds"
    shutil.copytree(PAPER_TABLE3_DIR, d)
    lines = (d / "summary.csv").read_text().splitlines()
    gone = lines[3].split(",")[0]
    (d / "summary.csv").write_text("\n".join(lines[:3] + lines[4:]) + "\n")
    with pytest.raises(m.DatasetError, match="%s.*has no measurement.*no row in summary.csv"
                       % gone) as e:
        demo.measured_table(d)
    assert str(d) in str(e.value)
