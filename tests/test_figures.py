"""Figures that must not mislead: readable heat-map labels, a linear and explained effect
ranking, and a SYNTHETIC mark on everything made from synthetic data (and only there)."""
import json

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from matplotlib.text import Text

from analysis import compare as cmpmod
from analysis import report
from analysis.compare import Comparison
from analysis.diagnose import Diagnosis, write_diagnosis
from analysis.measurements import Dataset, DatasetError, load_dataset, write_dataset
from analysis.plotting import compare_plots as cp
from analysis.plotting import surrogate_plots as sp

OBSERVABLES = ["v_mean_m_s", "f_col_hz", "yield_pct", "e_app", "v_in_m_s", "impact_phase_rad",
               "jar_amplitude_m", "vy_rms_m_s"]
FREQS = [22.5, 25.0, 27.5, 30.0]
BALLS = [17.5, 20.6]


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def _conditions():
    return pd.DataFrame([{"condition_id": "f%g_d%g" % (f, d), "frequency_hz": f,
                          "ball_diameter_mm": d} for d in BALLS for f in FREQS])


def _dataset(synthetic):
    cond = _conditions()
    summ = pd.DataFrame({"condition_id": cond["condition_id"], "v_mean_m_s": 2.0,
                         "v_mean_sd_m_s": 0.03, "f_col_hz": 50.0, "f_col_sd_hz": 1.0})
    meta = {"synthetic": True} if synthetic else {}
    return Dataset(name="hidden_toy" if synthetic else "lab_toy", description="test",
                   source="test", velocity_frame="lab", conditions=cond, summary=summ,
                   meta=meta)


def _comparison(observables=OBSERVABLES, seed=0):
    rng = np.random.default_rng(seed)
    rows = []
    for _, c in _conditions().iterrows():
        for o in observables:
            rows.append({"condition_id": c["condition_id"], "label": "x",
                         "frequency_hz": c["frequency_hz"],
                         "ball_diameter_mm": c["ball_diameter_mm"], "observable": o,
                         "time_min": np.nan, "measured": 1.0, "residual": 0.0,
                         "z": rng.normal(0.0, 2.0)})
    t = pd.DataFrame(rows)
    return Comparison(table=t, chi2=float((t["z"] ** 2).sum()), dof=len(t) - 2)


def _diagnosis(bound=True, hatched_gain=12.0):
    t = pd.DataFrame({
        "effect": ["induction_period", "temperature_rise", "viscoelastic_restitution",
                   "rolling_resistance", "jar_compliance_with_a_long_name", "air_drag"],
        "delta_chi2": [80.0, 19.3, 1.7, 0.02, hatched_gain, 0.0],
        "significant": [True, True, False, False, False, False],
        "identifiable": [True, True, True, True, False, False],
        "strength_at_bound": [False, bound, False, False, False, False]})
    t.insert(0, "rank", np.arange(1, len(t) + 1))
    for c in ("p_bonferroni", "strength", "strength_se", "footprint", "absorbed_frac"):
        t[c] = 0.5
    t["kind"] = "dem"
    return Diagnosis(table=t, baseline=None, calibrated=None, fits={}, structure=pd.DataFrame(),
                     status="effect", best="induction_period", verdict="", alpha=0.01,
                     threshold_delta_chi2=9.55, n_predict_calls=0)


def _texts(fig):
    return [t.get_text() for t in fig.findobj(Text) if t.get_visible()]


def _overlaps(labels, renderer):
    boxes = [t.get_window_extent(renderer=renderer) for t in labels
             if t.get_visible() and t.get_text()]
    bad = []
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i], boxes[j]
            if min(a.x1, b.x1) > max(a.x0, b.x0) and min(a.y1, b.y1) > max(a.y0, b.y0):
                bad.append((labels[i].get_text(), labels[j].get_text()))
    return bad


# ------------------------------------------------------------------------------ heat map

@pytest.mark.parametrize("layout", ["compare", "hidden_demo", "narrow", "two_columns"])
def test_heatmap_tick_labels_do_not_overlap(layout):
    obs = OBSERVABLES[:2] if layout == "two_columns" else OBSERVABLES
    cmp = _comparison(obs)
    if layout == "hidden_demo":            # heat map beside the staircase, as the demo draws it
        w, h = cp.heatmap_figsize(cmp)
        fig, axes = plt.subplots(1, 2, figsize=(w + 5.0, max(h, 4.0)),
                                 gridspec_kw={"width_ratios": [w, 5.0]})
        ax = axes[0]
        cp.plot_chi2_staircase(pd.DataFrame({"stage": ["baseline", "calibrated"],
                                             "chi2_dof": [9.0, 1.2]}), ax=axes[1])
    elif layout == "narrow":               # the old fixed width: labels must still clear
        fig, ax = plt.subplots(figsize=(5.5, 4.0))
    else:
        fig, ax = plt.subplots(figsize=cp.heatmap_figsize(cmp))
    cp.plot_residual_heatmap(cmp, ax=ax, dataset=_dataset(False))
    fig.tight_layout()
    r = fig.canvas.get_renderer()
    xt, yt = ax.get_xticklabels(), ax.get_yticklabels()
    assert len(xt) == len(obs) and len(yt) == len(FREQS) * len(BALLS)
    assert _overlaps(xt, r) == []
    assert _overlaps(yt, r) == []
    # labels stay inside the figure
    fb = fig.bbox
    for t in xt + yt:
        b = t.get_window_extent(renderer=r)
        assert b.x0 >= fb.x0 - 1 and b.x1 <= fb.x1 + 1 and b.y0 >= fb.y0 - 1
    # short condition labels on the rows, short observable names on the columns
    assert yt[0].get_text() == "17.5 mm / 22.5 Hz"
    assert xt[0].get_text() == "v_mean"


def test_heatmap_figure_width_grows_with_columns():
    w2, _ = cp.heatmap_figsize(_comparison(OBSERVABLES[:2]))
    w8, _ = cp.heatmap_figsize(_comparison(OBSERVABLES))
    assert w8 > w2 and w8 >= 3.4 + 0.6 * 8 - 1e-9


# ------------------------------------------------------------------------------ ranking

def test_ranking_is_linear_titled_and_explained():
    fig, ax = plt.subplots(figsize=cp.ranking_figsize(_diagnosis()))
    cp.plot_effect_ranking(_diagnosis(), ax=ax, dataset_name="toy_data")
    fig.tight_layout()
    assert ax.get_xscale() == "linear" and ax.get_yscale() == "linear"
    assert "toy_data" in ax.get_title() and ax.get_title().strip()
    # the threshold is a drawn, labelled line at its value
    thr = [ln for ln in ax.lines if np.allclose(ln.get_xdata(), 9.55)]
    assert thr, "no threshold line"
    assert any("threshold" in s and "9.55" in s for s in _texts(fig))
    # every mark used is in the legend
    leg = ax.get_legend()
    assert leg is not None
    words = [t.get_text() for t in leg.get_texts()]
    for key in ("significant", "not significant", "not identifiable", "threshold"):
        assert any(w.startswith(key) or key in w for w in words), key
    assert any("bound" in w for w in words)
    # hatching only on the non-identifiable bars, and the legend shows the hatch
    hatched = [b.get_hatch() for b in ax.patches[:6]]
    assert [bool(h) for h in hatched] == [False, False, False, False, True, True]
    assert any(h.get_hatch() for h in leg.legend_handles if hasattr(h, "get_hatch"))
    # a tiny gain is written out, not just drawn as an invisible bar
    assert any(s.startswith("0.02") for s in _texts(fig))
    # bars start at zero and the largest gain is inside the axis
    lo, hi = ax.get_xlim()
    assert lo == 0.0 and hi > 80.0


def test_ranking_legend_lists_only_marks_in_use():
    d = _diagnosis(bound=False)
    d.table["identifiable"] = True
    ax = cp.plot_effect_ranking(d)
    words = " | ".join(t.get_text() for t in ax.get_legend().get_texts())
    assert "bound" not in words and "not identifiable" not in words
    assert "threshold" in words and ax.get_title().strip()


def test_write_diagnosis_marks_synthetic(tmp_path):
    d = _diagnosis()
    write_diagnosis(d, tmp_path / "syn", dataset_name="hidden_toy", synthetic=True)
    write_diagnosis(d, tmp_path / "real", dataset_name="lab_toy")
    assert "SYNTHETIC" in (tmp_path / "syn" / "diagnosis.md").read_text()
    assert "SYNTHETIC" not in (tmp_path / "real" / "diagnosis.md").read_text()
    assert (tmp_path / "syn" / "ranking.png").stat().st_size > 1000


# ------------------------------------------------------------------------------ SYNTHETIC

def test_dataset_flag_is_read_and_checked(tmp_path):
    syn = load_dataset(write_dataset(_dataset(True), tmp_path / "syn"))
    real = load_dataset(write_dataset(_dataset(False), tmp_path / "real"))
    assert syn.synthetic is True and real.synthetic is False
    meta = json.loads((tmp_path / "syn" / "dataset.json").read_text())
    meta["synthetic"] = "yes"
    (tmp_path / "syn" / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(DatasetError, match="synthetic"):
        load_dataset(tmp_path / "syn")


@pytest.mark.parametrize("synthetic", [True, False])
def test_synthetic_mark_on_figures(synthetic):
    ds = _dataset(synthetic)
    cmp = _comparison()
    figs = []
    fig, ax = plt.subplots(figsize=cp.heatmap_figsize(cmp))
    cp.plot_residual_heatmap(cmp, ax=ax, dataset=ds)
    figs.append(fig)
    fig, ax = plt.subplots()                 # a caller's own title keeps the mark
    cp.plot_residual_heatmap(cmp, ax=ax, dataset=ds, title="before: no effect")
    figs.append(fig)
    fig, ax = plt.subplots()
    cp.plot_effect_ranking(_diagnosis(), ax=ax, dataset=ds)
    assert ds.name in ax.get_title()
    figs.append(fig)
    fig, ax = plt.subplots()
    cp.plot_chi2_staircase(pd.DataFrame({"stage": ["a", "b"], "chi2_dof": [3.0, 1.0]}), ax=ax,
                           synthetic=ds.synthetic)
    figs.append(fig)
    fig, ax = plt.subplots()
    cp.plot_yield_residuals(Comparison(table=pd.DataFrame(
        {"condition_id": ["c"], "label": ["c"], "observable": ["yield_pct"], "time_min": [5.0],
         "residual": [1.0], "sigma": [1.0]}), chi2=1.0, dof=1), ax=ax, synthetic=ds.synthetic)
    figs.append(fig)
    fig, ax = plt.subplots()
    sp.plot_yield_parity(pd.DataFrame({"yield_measured_pct": [10.0, 20.0],
                                       "yield_lr_pct": [11.0, 19.0]}), ax=ax,
                         reference="yield_measured_pct", synthetic=ds.synthetic)
    figs.append(fig)
    for fig in figs:
        texts = " ".join(_texts(fig))
        assert ("SYNTHETIC" in texts) == synthetic, texts[:200]


@pytest.mark.parametrize("synthetic", [True, False])
def test_compare_report_marks_synthetic(tmp_path, synthetic):
    ds = _dataset(synthetic)
    cmp = _comparison(["v_mean_m_s", "f_col_hz"])
    cmp.table["measured_sd"] = 0.1
    cmp.table["measured_sd_default"] = False
    cmp.table["model_sd_default"] = False
    cmp.table["model_mean"] = 1.0
    cmp.table["model_se"] = 0.1
    cmp.table["n_replicates"] = 3
    cmp.table["rel_residual_pct"] = 0.0
    page = cmpmod.markdown_page(cmp, ds, ["heatmap.png"])
    assert ("SYNTHETIC" in page) == synthetic
    out = cmpmod.write_report(cmp, ds, tmp_path / "out")
    assert (out / "heatmap.png").stat().st_size > 1000


@pytest.mark.parametrize("flag", [True, False])
def test_predict_page_does_not_call_synthetic_yields_measured(tmp_path, flag):
    d = tmp_path / "predict"
    d.mkdir()
    pd.DataFrame({"condition_id": ["f30_d20"], "frequency_hz": [30.0],
                  "abs_err_lr_vs_twin_pct": [0.5],
                  "abs_err_lr_vs_measured_pct": [2.0]}).to_csv(d / "table6_abs_errors.csv",
                                                               index=False)
    pd.DataFrame({"condition_id": ["f30_d20"], "time_min": [2.5]}).to_csv(
        d / "yield_comparison.csv", index=False)
    (d / "source.json").write_text(json.dumps({"yields": "toy", "yields_synthetic": flag}))
    (d / "fig14_yield_parity.png").write_bytes(report.PNG_MAGIC + b"\x00" * 16)
    report.main(["--results-dir", str(tmp_path)])
    page = (d / "README.md").read_text()
    if flag:
        assert "LR vs SYNTHETIC yields" in page and "vs measured" not in page
        assert "**SYNTHETIC DATA**" in page
    else:
        assert "LR vs measured" in page and "SYNTHETIC" not in page
