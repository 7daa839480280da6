"""analysis.report: pages from small synthetic study folders, problem pages, atomic writes."""
import json
import os
import shutil

import pandas as pd
import pytest

from analysis import report
from analysis.config import RESULTS_DIR

PNG = report.PNG_MAGIC + b"\x00" * 16  # enough for the magic-number check


def _calibration_folder(root, v_err=(1.25, -3.5)):
    d = root / "calibration"
    d.mkdir(parents=True)
    pd.DataFrame({"parameter": ["restitution", "amplitude_m"], "mean": [0.4321, 0.0125],
                  "sd": [0.0567, 0.0004], "q2.5": [0.32, 0.0117], "q50": [0.43, 0.0125],
                  "q97.5": [0.54, 0.0133], "prior_lower": [0.1, 0.01],
                  "prior_upper": [0.7, 0.016]}).to_csv(d / "parameters.csv", index=False)
    pd.DataFrame({"condition_id": ["f30_d17.5", "f25_d20.6"], "frequency_hz": [30, 25],
                  "ball_diameter_mm": [17.5, 20.6], "v_mean_measured_m_s": [2.57, 2.13],
                  "v_mean_twin_m_s": [2.6021, 2.0555], "v_err_pct": list(v_err),
                  "f_col_measured_hz": [60, 50], "f_col_twin_hz": [60.05, 50.05],
                  "f_col_err_pct": [0.08, 0.1], "v_err_paper_pct": [0.0, 0.47]}
                 ).to_csv(d / "table3_comparison.csv", index=False)
    (d / "summary.json").write_text(json.dumps({"dataset": "toy", "n_runs": 42,
                                                "new_runs": 5}))
    pd.DataFrame({"stage": ["calibrated", "twin rerun"], "chi2_dof": [1.23, 1.87]}).to_csv(
        d / "staircase.csv", index=False)
    (d / "parity.png").write_bytes(PNG)
    (d / "posterior_pairs.png").write_bytes(PNG)
    return d


def test_page_carries_the_numbers_of_the_csv(tmp_path):
    d = _calibration_folder(tmp_path)
    assert report.main(["--results-dir", str(tmp_path), "--strict"]) == 0
    page = (d / "README.md").read_text()
    assert "| restitution | - | 0.432 | 0.057 | [0.320, 0.540] | 0.1 - 0.7 |" in page
    assert "| amplitude_mm | mm | 12.500 | 0.400 |" in page  # metres shown in mm
    assert "+1.25" in page and "-3.50" in page and "2.602" in page
    # summary from the same numbers: mean |error| (1.25 + 3.5) / 2, max 3.5 > 3 %: goal not met
    assert "mean |error| 2.38 %, max 3.50 %" in page and "NOT met" in page
    assert "calibrated 1.23, twin rerun 1.87" in page
    assert "Twin runs used: 42" in page
    assert "![parity](parity.png)" in page and "![posterior_pairs](posterior_pairs.png)" in page
    index = (tmp_path / "README.md").read_text()
    assert "[calibration](calibration/README.md)" in index
    # folders that do not exist get no page and no index row
    assert not (tmp_path / "kinetics").exists() and "kinetics" not in index


def test_regenerated_study_updates_the_page(tmp_path):
    d = _calibration_folder(tmp_path)
    report.main(["--results-dir", str(tmp_path)])
    t = pd.read_csv(d / "table3_comparison.csv")
    t["v_err_pct"] = [0.5, -0.25]
    t.to_csv(d / "table3_comparison.csv", index=False)
    report.main(["--results-dir", str(tmp_path)])
    page = (d / "README.md").read_text()
    assert "mean |error| 0.38 %, max 0.50 %" in page and "-3.50" not in page


def test_missing_file_gives_a_page_naming_it_and_exit_code_only_when_strict(tmp_path):
    d = _calibration_folder(tmp_path)
    (d / "table3_comparison.csv").unlink()
    (d / "parity.png").write_text("not an image")
    assert report.main(["--results-dir", str(tmp_path)]) == 0
    assert report.main(["--results-dir", str(tmp_path), "--strict"]) == 1
    page = (d / "README.md").read_text()
    assert "PAGE NOT BUILT" in page
    assert "| `table3_comparison.csv` | missing |" in page
    assert "| `parity.png` | is not a PNG file |" in page
    assert "`python -m analysis.calibrate`" in page  # how to regenerate it
    assert "**problems**" in (tmp_path / "README.md").read_text()


@pytest.mark.parametrize("content, expected", [
    ("", "unreadable"),
    ("parameter,mean\nrestitution,0.4\n", "missing column(s) sd, q2.5, q97.5"),
    ("parameter,mean,sd,q2.5,q97.5\nrestitution,abc,0.1,0.2,0.3\n",
     "row 1, column mean: 'abc' is not a number"),
    ("parameter,mean,sd,q2.5,q97.5\n", "has 0 data row(s)"),
])
def test_malformed_csv_is_named_with_what_is_wrong(tmp_path, content, expected):
    d = _calibration_folder(tmp_path)
    (d / "parameters.csv").write_text(content)
    report.main(["--results-dir", str(tmp_path)])
    page = (d / "README.md").read_text()
    assert "`parameters.csv`" in page and expected in page


def test_malformed_json_and_unexpected_content_never_crash(tmp_path):
    d = _calibration_folder(tmp_path)
    (d / "summary.json").write_text("{not json")
    assert report.main(["--results-dir", str(tmp_path)]) == 0
    assert "`summary.json` | unreadable" in (d / "README.md").read_text()
    # a builder that fails on something the checks did not foresee still gives a problem page
    study = report.Study("calibration", "t", "a", "r", lambda f: 1 / 0)
    text, res = report.render_page(study, d)
    assert not res.ok and "ZeroDivisionError" in text


def test_failed_write_leaves_the_old_page_and_no_temp_file(tmp_path, monkeypatch):
    d = _calibration_folder(tmp_path)
    report.main(["--results-dir", str(tmp_path)])
    before = (d / "README.md").read_text()
    (d / "table3_comparison.csv").unlink()

    def boom(src, dst):
        raise OSError("disk full")
    monkeypatch.setattr(report.os, "replace", boom)
    assert report.main(["--results-dir", str(tmp_path)]) == 2
    assert (d / "README.md").read_text() == before
    assert [p.name for p in d.iterdir() if p.name.startswith(".")] == []


def test_foreign_pages_are_linked_not_written(tmp_path):
    for name, page in (("apparatus", "report.md"), ("demo", "README.md")):
        (tmp_path / name).mkdir()
        (tmp_path / name / page).write_text("their page\n")
    (tmp_path / "runs").mkdir()
    assert report.main(["--results-dir", str(tmp_path), "--strict"]) == 0
    for name, page in (("apparatus", "report.md"), ("demo", "README.md")):
        assert (tmp_path / name / page).read_text() == "their page\n"
    index = (tmp_path / "README.md").read_text()
    assert "[apparatus](apparatus/report.md)" in index
    assert "[demo](demo/README.md)" in index
    assert "runs" not in index.split("| folder")[1]
    # a foreign folder without its page yet: listed, no page written for it
    other = tmp_path / "other"
    (other / "demo").mkdir(parents=True)
    (other / "runs").mkdir()
    assert report.main(["--results-dir", str(other), "--strict"]) == 0
    index = (other / "README.md").read_text()
    assert "[demo](demo/)" in index and "no README.md or report.md" in index
    assert not (other / "demo" / "README.md").exists()


def test_synthetic_source_is_flagged(tmp_path):
    d = tmp_path / "predict"
    d.mkdir()
    pd.DataFrame({"condition_id": ["f30_d20"], "frequency_hz": [30.0],
                  "abs_err_lr_vs_twin_pct": [0.123]}).to_csv(d / "table6_abs_errors.csv",
                                                              index=False)
    pd.DataFrame({"condition_id": ["f30_d20"], "time_min": [2.5]}).to_csv(
        d / "yield_comparison.csv", index=False)
    (d / "source.json").write_text(json.dumps({"yields": "SYNTHETIC toy"}))
    (d / "fig14_yield_parity.png").write_bytes(PNG)
    report.main(["--results-dir", str(tmp_path)])
    page = (d / "README.md").read_text()
    assert "**SYNTHETIC DATA**" in page and "SYNTHETIC toy" in page and "| 0.12 |" in page


def test_bad_results_dir_is_a_clear_error(tmp_path, capsys):
    assert report.main(["--results-dir", str(tmp_path / "nope")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_committed_study_folders_build_without_problems(tmp_path):
    """Every committed study folder parses (copied: the real pages are not touched)."""
    copied = 0
    for s in report.STUDIES:
        src = RESULTS_DIR / s.name
        if src.is_dir():
            shutil.copytree(src, tmp_path / s.name,
                            ignore=shutil.ignore_patterns("*.joblib", "posterior_samples.csv",
                                                          "*.stl", "README.md"))
            copied += 1
    if not copied:
        pytest.skip("no committed study folders")
    results = report.build_reports(tmp_path)
    assert [(r.study, r.problems) for r in results if not r.ok] == []
    assert all(os.path.getsize(r.path) > 200 for r in results)


def test_studies_page_shows_figure8_and_sobol(tmp_path):
    """The sensitivity subfolder (Figure 8 on the twin, Sobol) is on the studies page, with the
    count of matching grid points read from its CSV."""
    src = RESULTS_DIR / "studies"
    if not (src / "sensitivity" / "figure8_grid.csv").is_file():
        pytest.skip("no committed sensitivity study")
    shutil.copytree(src, tmp_path / "studies", ignore=shutil.ignore_patterns("*.stl", "README.md"))
    grid = pd.read_csv(src / "sensitivity" / "figure8_grid.csv")
    n = int(grid["matches"].astype(str).str.lower().eq("true").sum())
    report.build_reports(tmp_path)
    page = (tmp_path / "studies" / "README.md").read_text()
    assert "%d reproduce the measured 2.13 m/s" % n in page
    assert "| restitution |" in page and "![figure8.png](sensitivity/figure8.png)" in page
    # a broken sensitivity CSV is named on the page
    (tmp_path / "studies" / "sensitivity" / "figure8_grid.csv").write_text("a,b\n1,2\n")
    res = {r.study: r for r in report.build_reports(tmp_path)}
    assert not res["studies"].ok and "figure8_grid.csv" in str(res["studies"].problems)
