"""The cached-loop benchmark's comparison of two loop folders (analysis.bench.loop_cached)."""
import numpy as np
import pandas as pd

from analysis.bench.loop_cached import TABLES, largest_difference


def _folder(path, scale=1.0, text="effect", extra=False):
    path.mkdir()
    for t in TABLES:
        df = pd.DataFrame({"name": ["a", text], "value": [2.0 * scale, np.nan],
                           "chi2": [10.0, 1.0], "significant": [True, False]})
        if extra:
            df["more"] = 1.0
        df.to_csv(path / (t + ".csv"), index=False)
    return path


def test_the_largest_relative_difference_of_two_loops_numbers(tmp_path):
    a = _folder(tmp_path / "a")
    assert largest_difference(a, _folder(tmp_path / "b")) == 0.0
    assert np.isclose(largest_difference(a, _folder(tmp_path / "c", scale=1 + 1e-7)), 1e-7,
                      rtol=1e-3)
    # other words, other columns: not the same tables at any tolerance
    assert largest_difference(a, _folder(tmp_path / "d", text="other")) == np.inf
    assert largest_difference(a, _folder(tmp_path / "e", extra=True)) == np.inf
