"""analysis.linalg against the general functions it stands in for."""
import numpy as np
import pytest
from scipy.linalg import cholesky, solve_triangular

from analysis.linalg import solve_lower


@pytest.mark.parametrize("order", ["C", "F"])
def test_solve_lower_is_scipys_solve_triangular_to_the_last_digit(order):
    """The same bits as solve_triangular(L, b, lower=True) for a C- and an F-ordered L, a
    vector, a matrix, a transposed view and no column at all; a singular L is refused."""
    rng = np.random.default_rng(11)
    A = rng.normal(size=(30, 30))
    L = np.array(cholesky(A @ A.T + 30 * np.eye(30), lower=True), order=order)
    K = rng.normal(size=(7, 30))
    for b in (rng.normal(size=30), rng.normal(size=(30, 5)), K.T, np.empty((30, 0))):
        ref = solve_triangular(L, b, lower=True, check_finite=False)
        got = solve_lower(L, b)
        assert got.shape == ref.shape and np.array_equal(got, ref)
    L[3, 3] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        solve_lower(L, np.ones(30))
