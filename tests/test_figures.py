"""Figures that must not mislead: a linear and explained effect ranking, and a SYNTHETIC mark
on everything made from synthetic data (and only there)."""
import json

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from matplotlib.text import Text

from analysis import report
from analysis.diagnose import Diagnosis
from analysis.measurements import Dataset, DatasetError, load_dataset, write_dataset
from analysis.plotting import loop_plots as lp
from analysis.plotting import surrogate_plots as sp

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
                     threshold_delta_chi2=9.55)


def _texts(fig):
    return [t.get_text() for t in fig.findobj(Text) if t.get_visible()]


# ------------------------------------------------------------------------------ ranking

def test_ranking_is_linear_titled_and_explained():
    fig, ax = plt.subplots(figsize=lp.ranking_figsize(_diagnosis()))
    lp.plot_effect_ranking(_diagnosis(), ax=ax, dataset_name="toy_data")
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
    ax = lp.plot_effect_ranking(d)
    words = " | ".join(t.get_text() for t in ax.get_legend().get_texts())
    assert "bound" not in words and "not identifiable" not in words
    assert "threshold" in words and ax.get_title().strip()


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
    figs = []
    fig, ax = plt.subplots()
    lp.plot_effect_ranking(_diagnosis(), ax=ax, dataset=ds)
    assert ds.name in ax.get_title()
    figs.append(fig)
    fig, ax = plt.subplots()                 # a caller's own title keeps the mark
    lp.plot_effect_ranking(_diagnosis(), ax=ax, dataset=ds, title="step 1")
    figs.append(fig)
    fig, ax = plt.subplots()
    lp.plot_loop_staircase(pd.DataFrame({"stage": ["baseline", "calibrated"],
                                         "chi2_dof": [3.0, 1.0], "dof": [16, 12]}), ax=ax,
                           synthetic=ds.synthetic)
    figs.append(fig)
    fig, ax = plt.subplots()
    sp.plot_yield_parity(pd.DataFrame({"yield_measured_pct": [10.0, 20.0],
                                       "yield_lr_pct": [11.0, 19.0]}), ax=ax,
                         reference="yield_measured_pct", synthetic=ds.synthetic)
    figs.append(fig)
    for fig in figs:
        texts = " ".join(_texts(fig))
        assert ("SYNTHETIC" in texts) == synthetic, texts[:200]


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
