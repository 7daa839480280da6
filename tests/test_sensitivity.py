"""Sensitivity: Figure-8 grid design and multiplicity, Sobol indices of known functions."""
import numpy as np
import pandas as pd
import pytest
from threadpoolctl import threadpool_limits

from analysis import sensitivity as sens
from analysis.emulator import GPEmulator


@pytest.fixture(autouse=True)
def one_blas_thread():
    with threadpool_limits(1):
        yield


def test_figure8_design_shape_and_bounds():
    cfgs = sens.figure8_design(replicates=3)
    n_points = np.prod([len(v) for v in sens.FIGURE8_LEVELS.values()])
    assert len(cfgs) == 3 * n_points
    df = pd.DataFrame(cfgs)
    assert (df["frequency_hz"] == 25.0).all() and (df["ball_diameter_m"] == 0.0206).all()
    assert sorted(df["seed"].unique()) == [0, 1, 2]
    for k, (lo, hi) in sens.CONTACT_BOUNDS.items():
        assert df[k].between(lo, hi).all()
    with pytest.raises(ValueError, match="static_friction = 0.9 outside"):
        sens.figure8_design(levels={"static_friction": (0.5, 0.9)})


def test_grid_study_mean_sd_and_multiplicity():
    """v = 2.13 m/s on the plane 2*C_R - RF = 0 (several grid points: multiplicity), far
    elsewhere, replicate noise sd 0.02 m/s drawn per seed."""
    noise_sd = 0.02

    def simulate(configs):
        rows = []
        for c in configs:
            rng = np.random.default_rng([int(c["seed"]), int(1000 * c["restitution"]),
                                         int(1000 * c["rolling_friction"]),
                                         int(1000 * c["static_friction"])])
            v = 2.13 + 1.5 * (2 * c["restitution"] - c["rolling_friction"]) \
                + noise_sd * rng.standard_normal()
            rows.append({"v_mean_m_s": v, "status": "done", "motion_mode": "flight"})
        return pd.DataFrame(rows)

    levels = {"restitution": (0.1, 0.2, 0.4), "static_friction": (0.3, 0.7),
              "rolling_friction": (0.2, 0.4)}
    cfgs = sens.figure8_design(levels=levels, replicates=12)
    study = sens.grid_study(simulate, cfgs, names=list(levels), meas_rel_sd=0.0)
    assert len(study.summary) == 12
    assert abs(study.pooled_sd_m_s - noise_sd) < 0.3 * noise_sd
    expected = 2.13 + 1.5 * (2 * study.summary["restitution"] - study.summary["rolling_friction"])
    se = study.summary["v_mean_m_s_sd"] / np.sqrt(12)
    assert ((study.summary["v_mean_m_s_mean"] - expected).abs() < 4 * se).all()
    m = study.matches
    truth = np.isclose(2 * m["restitution"], m["rolling_friction"])
    assert truth.all() and len(m) == 4          # (0.1, 0.2) and (0.2, 0.4), both SF levels


def test_sobol_linear_model_known_shares():
    a = np.array([1.0, 2.0, 3.0])
    model = lambda X: X @ a                                     # noqa: E731
    res = sens.sobol_indices(model, {"x1": (0, 1), "x2": (0, 1), "x3": (0, 1)},
                             n_base=2048, seed=1)
    truth = a ** 2 / np.sum(a ** 2)
    assert np.all(np.abs(res.S1 - truth) <= res.S1_conf)
    assert np.all(np.abs(res.ST - truth) <= res.ST_conf)
    assert res.n_evaluations == 2048 * 5


def test_sobol_ishigami_within_confidence_intervals():
    from SALib.test_functions import Ishigami
    a, b = 7.0, 0.1
    v = a ** 2 / 8 + b * np.pi ** 4 / 5 + b ** 2 * np.pi ** 8 / 18 + 0.5
    v1 = 0.5 * (1 + b * np.pi ** 4 / 5) ** 2
    v2 = a ** 2 / 8
    v13 = 8 * b ** 2 * np.pi ** 8 / 225
    s1 = np.array([v1, v2, 0.0]) / v
    st = np.array([v1 + v13, v2, v13]) / v
    bounds = {"x1": (-np.pi, np.pi), "x2": (-np.pi, np.pi), "x3": (-np.pi, np.pi)}
    res = sens.sobol_indices(Ishigami.evaluate, bounds, n_base=4096, seed=3)
    assert np.all(np.abs(res.S1 - s1) <= res.S1_conf), (res.S1, s1, res.S1_conf)
    assert np.all(np.abs(res.ST - st) <= res.ST_conf), (res.ST, st, res.ST_conf)
    assert list(res.to_frame().columns) == ["S1", "S1_conf", "ST", "ST_conf"]


def test_sobol_on_emulator_of_linear_twin():
    rng = np.random.default_rng(5)
    bounds = {"restitution": (0.1, 0.7), "static_friction": (0.3, 0.7),
              "frequency_hz": (22.5, 30.0)}
    X = np.column_stack([rng.uniform(*bounds[k], 60) for k in bounds])
    y = 3.0 * X[:, 0] - 1.0 * X[:, 1] + 0.1 * X[:, 2]
    em = GPEmulator(bounds, outputs=("v_mean_m_s",), random_state=0).fit(X, y)
    res = sens.emulator_sobol(em, bounds, fixed={"frequency_hz": 25.0}, n_base=1024, seed=2)
    var = np.array([3.0 ** 2 * 0.6 ** 2, 1.0 ** 2 * 0.4 ** 2]) / 12
    truth = var / var.sum()
    assert res.names == ["restitution", "static_friction"]
    assert np.all(np.abs(res.S1 - truth) <= res.S1_conf)
    with pytest.raises(ValueError, match="no bounds"):
        sens.emulator_sobol(em, {"restitution": (0.1, 0.7)})


def test_sobol_rejects_nan_model():
    with pytest.raises(ValueError, match="NaN"):
        sens.sobol_indices(lambda X: np.full(len(X), np.nan), {"a": (0, 1), "b": (0, 1)},
                           n_base=64)
