"""The effect-transfer study's leave-one-out score, on changes made from known truth."""
import numpy as np
import pandas as pd

from analysis.studies.effect_transfer import loo_errors, transfer_table


def _groups(rng, n, truth, se=0.01):
    f = rng.uniform(20, 32, n)
    d = rng.uniform(14, 22, n)
    y = truth(f, d) + rng.normal(0, se, n)
    return pd.DataFrame({"frequency_hz": f, "ball_diameter_mm": d, "change": y,
                         "change_se": se})


def test_plane_truth_transfers_at_the_noise_and_a_constant_does_not():
    rng = np.random.default_rng(3)
    ratios_plane, ratios_const = [], []
    for _ in range(200):
        g = _groups(rng, 14, lambda f, d: 0.05 + 0.01 * (f - 26) - 0.02 * (d - 18))
        r = loo_errors(g)
        ratios_plane.append(r["ratio_plane"])
        ratios_const.append(r["ratio_constant"])
    # leave-one-out of a 3-coefficient plane on 14 points: the error of a new point
    # is sqrt(1 + leverage) of the noise, about 1.1 on average
    assert 0.95 < np.median(ratios_plane) < 1.3
    assert np.median(ratios_const) > 5


def test_structure_beyond_a_plane_shows_as_a_ratio_above_one():
    rng = np.random.default_rng(4)
    r = [loo_errors(_groups(rng, 14, lambda f, d: 0.05 * np.sin(f)))["ratio_plane"]
         for _ in range(50)]
    assert np.median(r) > 2


def test_transfer_table_needs_enough_conditions():
    rng = np.random.default_rng(5)
    g = _groups(rng, 5, lambda f, d: 0 * f).assign(anchor_key="a", effect="e", level=1.0,
                                                   observable="v_mean_m_s")
    assert len(transfer_table(g, min_conditions=6)) == 0
    assert len(transfer_table(g, min_conditions=5)) == 1
