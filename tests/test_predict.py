"""predict: surrogate + kinetics -> yield; consistency with the known truth; input errors; CLI."""
import json

import numpy as np
import pandas as pd
import pytest

from analysis import kinetics as kin
from analysis import predict as pr
from analysis import surrogate as sur
from analysis import yield_data as yd


@pytest.fixture(scope="module")
def kfit():
    ds = yd.load_yield_dataset(yd.SYNTHETIC_DATASET_DIR)
    energy = kin.energy_for_conditions(ds.conditions, kin.table3_energy_inputs())
    data = kin.attach_cumulative_energy(ds.yields, energy)
    return kin.fit_kinetics(data["e_tot_j"], data["yield_pct"], phase=data["phase"], n_boot=20,
                            source="SYNTHETIC test")


@pytest.fixture(scope="module")
def bundle():
    table = sur.synthetic_twin_table(v_rel_sd=0.005, f_col_sd_hz=0.2, n_replicates=2, seed=11)
    return sur.fit_bundle(table, kinds=("lr", "gp"))


@pytest.fixture(scope="module")
def predictor(bundle, kfit):
    return pr.Predictor(surrogate=bundle, kinetics=kfit, kind="lr")


def test_query_chain_is_consistent(predictor, kfit):
    t = np.array([5.0, 15.0, 30.0])
    out = predictor.query(27.5, 0.020, t)
    assert len(out) == 3
    r = out.iloc[0]
    assert np.isclose(r["e_kin_j"], 0.5 * kin.ball_mass_kg(0.020) * r["v_mean_m_s"] ** 2)
    assert np.allclose(out["e_tot_j"], r["e_kin_j"] * r["f_col_hz"] * t * 60)
    direct = kin.predict_yield(kfit, r["e_kin_j"], r["f_col_hz"], t)
    assert np.allclose(out["yield_pct"], direct["yield_pct"])
    assert not out["out_of_domain"].any()
    # surrogate outputs near the known truth (noise 0.5 %)
    v, fc = sur.synthetic_truth(27.5, 0.020)
    assert abs(r["v_mean_m_s"] / v - 1) < 0.01 and abs(r["f_col_hz"] / fc - 1) < 0.01


def test_gp_query_carries_sd(bundle, kfit):
    out = pr.Predictor(bundle, kfit, kind="gp").query(25.0, 0.0175, 10.0)
    assert out["v_mean_sd_m_s"].iloc[0] > 0 and out["f_col_sd_hz"].iloc[0] > 0


def test_out_of_domain_flag(predictor):
    assert predictor.query(40.0, 0.020, 10.0)["out_of_domain"].all()
    assert predictor.query(25.0, 0.010, 10.0)["out_of_domain"].all()


@pytest.mark.parametrize("args, match", [
    ((27.5, 0.020, -1.0), ">= 0"),
    ((27.5, 0.020, [10.0, 5.0]), "order"),
    ((0.0, 0.020, 10.0), "frequency_hz"),
    ((27.5, -0.02, 10.0), "ball_diameter_m"),
    ((27.5, 0.020, [np.nan]), "finite"),
    (("fast", 0.020, 10.0), "number"),
])
def test_bad_inputs(predictor, args, match):
    with pytest.raises(pr.PredictInputError, match=match):
        predictor.query(*args)


def test_ball_larger_than_jar(predictor):
    with pytest.raises(pr.PredictInputError, match="jar"):
        predictor.query(27.5, 0.020, 10.0, jar_volume_m3=3e-6)


def test_surrogate_yield_matches_truth_yield(kfit, bundle):
    """Table 6 analogue on known truth: yields from surrogate outputs vs from true outputs."""
    cond = pd.DataFrame({"condition_id": ["a", "b", "c"], "frequency_hz": [25.0, 27.5, 30.0],
                         "ball_diameter_mm": [20.0, 20.0, 20.0]})
    f = cond["frequency_hz"].to_numpy()
    v, fc = sur.synthetic_truth(f, 0.020)
    twin = pd.DataFrame({"frequency_hz": f, "ball_diameter_m": 0.020, "v_mean_m_s": v,
                         "f_col_hz": fc, "source": "truth"})
    tab = pr.compare_yield_sources(kfit, twin, bundle, cond, times_min=np.arange(0, 41, 2.5))
    assert len(tab) == 3 * 17
    # the yield difference is the energy difference times the local slope of the yield curve:
    # bounded by the steepest segment (powder line or wax ramp) times |E_sur - E_twin|
    bp = kfit.boundaries
    y1 = float(kfit.line.predict([bp.powder_wax_j])["yield_pct"].iloc[0])
    wax_slope = (100.0 - y1) / (bp.wax_complete_j - bp.powder_wax_j) * 1e3      # %/kJ
    steepest = max(kfit.line.params["a_pct_per_kj"], wax_slope) / 1e3           # %/J
    for k in ("lr", "gp"):
        de = np.abs(tab[f"e_tot_{k}_j"] - tab["e_tot_twin_j"])
        assert (de[tab["time_min"] > 0] / tab["e_tot_twin_j"][tab["time_min"] > 0]).max() < 0.03
        assert (tab[f"abs_err_{k}_vs_twin_pct"] <= steepest * de + 1e-9).all()
    s = pr.summarize_comparison(tab)
    assert list(s["condition_id"]) == ["a", "b", "c"]


def test_cli_table_and_json(tmp_path, bundle, kfit, capsys):
    bpath = bundle.save(tmp_path / "s.joblib")
    kpath = tmp_path / "k.json"
    kfit.save(kpath)
    base = ["--surrogate", str(bpath), "--kinetics", str(kpath), "--frequency-hz", "27.5",
            "--ball-diameter-mm", "20"]
    assert pr.main(base + ["--time-min", "15"]) == 0
    txt = capsys.readouterr().out
    assert "yield_pct" in txt and "powder" in txt
    assert pr.main(base + ["--time-min", "5", "30", "--json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert len(js["rows"]) == 2 and js["rows"][1]["regime"] in ("wax", "complete")
    assert pr.main(base + ["--time-min", "30", "5"]) == 2
    assert "order" in capsys.readouterr().err
    assert pr.main(["--surrogate", str(bpath), "--kinetics", str(kpath), "--time-min", "5"]) == 2


def test_compare_uses_the_saved_surrogates_not_the_twin_table(tmp_path, bundle, kfit):
    """--compare --twin-table T: T gives the twin-output yields; the surrogates under test stay
    the saved ones (training them on T would compare the twin with itself)."""
    bpath = bundle.save(tmp_path / "s.joblib")
    kpath = tmp_path / "k.json"
    kfit.save(kpath)
    # a twin at the yield conditions (20 mm ball) that the bundle never saw: the bundle's own
    # prediction there, 5 % faster
    rows = [{"frequency_hz": f, "ball_diameter_m": 0.020,
             "v_mean_m_s": 1.05 * float(bundle.predict(f, 0.020)["v_mean_m_s"].iloc[0]),
             "f_col_hz": 2 * f, "seed": 0} for f in (25.0, 27.5, 30.0)]
    tpath = tmp_path / "twin.csv"
    pd.DataFrame(rows).to_csv(tpath, index=False)
    out = tmp_path / "cmp"
    assert pr.main(["--compare", "--surrogate", str(bpath), "--kinetics", str(kpath),
                    "--twin-table", str(tpath), "--out", str(out)]) == 0
    src = json.loads((out / "source.json").read_text())
    assert src["surrogate"] == bundle.source and "twin.csv" not in src["surrogate"]
    tab = pd.read_csv(out / "yield_comparison.csv")
    # the surrogate's yields differ from the (5 % faster) twin's: it was not trained on it
    lr = tab["yield_lr_pct"].to_numpy(float)
    tw = tab["yield_twin_pct"].to_numpy(float)
    ok = np.isfinite(lr) & np.isfinite(tw) & (tw > 5)
    assert ok.sum() > 3 and np.median(np.abs(lr[ok] / tw[ok] - 1)) > 0.03
