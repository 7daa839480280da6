"""Regime boundaries of the kinetics stage: the powder/wax and wax/complete energies [J].

Three estimates: the paper's candidate-breakpoint least squares, a continuous three-segment
hinge fit (both with case-resampling bootstrap intervals), and the boundaries read from recorded
phase labels (label gap, or a logistic fit where labels overlap).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from analysis.kinetics.model import REGIMES, KineticsInputError


@dataclass
class BoundaryResult:
    """Powder/wax and wax/complete boundaries in cumulative energy [J].

    Attributes
    ----------
    method : str - "candidates" (paper: breakpoints between data, least squares of a piecewise
        model), "continuous" (continuous 3-segment hinge, profile least squares on a fine grid)
        or "phase" (from recorded phase labels)
    params : Series - powder_wax_j, wax_complete_j (and for the LS methods the segment
        coefficients)
    ci : DataFrame - index powder_wax_j, wax_complete_j; columns lower, upper [J]
        (bootstrap percentile interval for LS methods, label gap or logistic for "phase")
    boot : ndarray, shape (n_boot, 2) - bootstrap replicates (empty for "phase")
    sse : float - residual sum of squares of the piecewise model (nan for "phase")
    residuals : ndarray, shape (n,) - residuals of the piecewise model [%] (empty for "phase")
    """

    method: str
    params: pd.Series
    ci: pd.DataFrame
    boot: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    sse: float = float("nan")
    residuals: np.ndarray = field(default_factory=lambda: np.empty(0))

    @property
    def powder_wax_j(self) -> float:
        return float(self.params["powder_wax_j"])

    @property
    def wax_complete_j(self) -> float:
        return float(self.params["wax_complete_j"])

    @property
    def stderr(self) -> pd.Series:
        if self.boot.shape[0] > 1:
            return pd.Series(self.boot.std(axis=0, ddof=1), index=["powder_wax_j", "wax_complete_j"])
        return pd.Series([np.nan, np.nan], index=["powder_wax_j", "wax_complete_j"])

    def to_frame(self) -> pd.DataFrame:
        se = self.stderr
        rows = []
        for name in ("powder_wax_j", "wax_complete_j"):
            rows.append(dict(method=self.method, boundary=name, value_j=float(self.params[name]),
                             stderr_j=float(se[name]), ci_lo_j=float(self.ci.loc[name, "lower"]),
                             ci_hi_j=float(self.ci.loc[name, "upper"]), n_boot=self.boot.shape[0],
                             sse=self.sse))
        return pd.DataFrame(rows)

    def to_dict(self) -> dict:
        return {"method": self.method, "params": {k: float(v) for k, v in self.params.items()},
                "ci": {k: [float(self.ci.loc[k, "lower"]), float(self.ci.loc[k, "upper"])]
                       for k in self.ci.index},
                "stderr": {k: float(v) for k, v in self.stderr.items()}, "sse": self.sse,
                "boot": self.boot.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "BoundaryResult":
        ci = pd.DataFrame({k: {"lower": v[0], "upper": v[1]} for k, v in d["ci"].items()}).T
        boot = np.asarray(d.get("boot", []), dtype=float).reshape(-1, 2)
        return cls(method=d["method"], params=pd.Series(d["params"]), ci=ci, boot=boot,
                   sse=float(d["sse"]))


def _seg_sums(e, x):
    """Prefix sums for O(1) OLS sums of squares of contiguous (sorted) segments."""
    z = np.zeros(1)
    return {k: np.concatenate([z, np.cumsum(v)]) for k, v in
            (("n", np.ones_like(e)), ("e", e), ("x", x), ("ee", e * e), ("ex", e * x),
             ("xx", x * x))}


def _sse_line(S, i, j):
    """SSE of an OLS line through sorted points i..j-1 (vectorised over i, j arrays)."""
    n = S["n"][j] - S["n"][i]
    se, sx = S["e"][j] - S["e"][i], S["x"][j] - S["x"][i]
    see, sex, sxx = S["ee"][j] - S["ee"][i], S["ex"][j] - S["ex"][i], S["xx"][j] - S["xx"][i]
    with np.errstate(invalid="ignore", divide="ignore"):
        cee = see - se * se / n
        cex = sex - se * sx / n
        cxx = sxx - sx * sx / n
        out = cxx - np.where(cee > 1e-12, cex * cex / cee, 0.0)
    return np.maximum(out, 0.0)


def _sse_const(S, i, j):
    n = S["n"][j] - S["n"][i]
    sx, sxx = S["x"][j] - S["x"][i], S["xx"][j] - S["xx"][i]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.maximum(sxx - sx * sx / n, 0.0)


def _boundaries_candidates(e, x, min_points=(3, 3, 2)):
    """Paper's method: breakpoints at the gaps between sorted energies; powder line, wax line,
    complete constant; the pair with the least total SSE wins. Returns (E1, E2, sse, i, j)."""
    order = np.argsort(e, kind="stable")
    e, x = e[order], x[order]
    n = e.size
    S = _seg_sums(e, x)
    gaps = np.flatnonzero(np.diff(e) > 0) + 1        # split index k: points [0,k) | [k, n)
    I, J = np.meshgrid(gaps, gaps, indexing="ij")
    ok = (I >= min_points[0]) & (J - I >= min_points[1]) & (n - J >= min_points[2])
    if not ok.any():
        raise KineticsInputError("too few distinct energies to place two regime boundaries "
                                 f"(need >= {sum(min_points)} points)")
    I, J = I[ok], J[ok]
    sse = _sse_line(S, np.zeros_like(I), I) + _sse_line(S, I, J) + _sse_const(S, J, np.full_like(J, n))
    k = int(np.nanargmin(sse))
    i, j = int(I[k]), int(J[k])
    return 0.5 * (e[i - 1] + e[i]), 0.5 * (e[j - 1] + e[j]), float(sse[k]), (e[i - 1], e[i]), (e[j - 1], e[j])


def _hinge_basis(e, e1, e2):
    """Design of the continuous 3-segment model, batched: e (n,), e1/e2 (G,) -> (G, n, 3)."""
    e = e[None, :]
    e1 = np.asarray(e1)[:, None]
    e2 = np.asarray(e2)[:, None]
    return np.stack([np.ones(np.broadcast_shapes(e.shape, e1.shape)),
                     np.minimum(e, e1), np.clip(e - e1, 0.0, e2 - e1)], axis=-1)


def _hinge_sse(e, x, e1, e2):
    B = _hinge_basis(e, e1, e2)
    BtB = np.einsum("gni,gnj->gij", B, B) + 1e-9 * np.eye(3)
    Btx = np.einsum("gni,n->gi", B, x)
    coef = np.linalg.solve(BtB, Btx[..., None])[..., 0]
    r = x[None, :] - np.einsum("gni,gi->gn", B, coef)
    return (r * r).sum(axis=1), coef


def _boundaries_continuous(e, x, min_points=(3, 2, 2), n_grid=60, n_refine=4):
    """Continuous hinge: X = b + a*min(E,E1) + s*clip(E-E1, 0, E2-E1); profile LS over (E1, E2)."""
    es = np.sort(e)
    n = es.size
    if n < sum(min_points):
        raise KineticsInputError(f"need >= {sum(min_points)} points to place two boundaries, got {n}")
    lo, hi = es[min_points[0] - 1], es[n - min_points[2]]
    if not hi > lo:
        raise KineticsInputError("energies do not spread enough to place two boundaries")
    g1 = np.linspace(lo, hi, n_grid)
    span = hi - lo
    best = None
    for level in range(n_refine + 1):
        E1, E2 = np.meshgrid(g1, g1 if level == 0 else g2, indexing="ij")
        E1, E2 = E1.ravel(), E2.ravel()
        n_below = np.searchsorted(es, E1, side="right")
        n_mid = np.searchsorted(es, E2, side="right") - n_below
        n_above = n - np.searchsorted(es, E2, side="right")
        ok = (E2 > E1) & (n_below >= min_points[0]) & (n_mid >= min_points[1]) & (n_above >= min_points[2])
        if not ok.any():
            if best is None:
                raise KineticsInputError("no admissible pair of boundaries for these energies")
            break
        sse, coef = _hinge_sse(e, x, E1[ok], E2[ok])
        k = int(np.argmin(sse))
        cand = (float(sse[k]), float(E1[ok][k]), float(E2[ok][k]), coef[k])
        if best is None or cand[0] <= best[0]:
            best = cand
        step = span / (n_grid - 1) / (4 ** level)
        g1 = np.linspace(best[1] - 2 * step, best[1] + 2 * step, 17)
        g2 = np.linspace(best[2] - 2 * step, best[2] + 2 * step, 17)
    sse, e1, e2, coef = best
    return e1, e2, sse, coef


def find_boundaries(e_tot_j, yield_pct, method: str = "continuous", n_boot: int = 200,
                    alpha: float = 0.05, random_state=0) -> BoundaryResult:
    """Regime boundaries from yield data by least squares of a piecewise model.

    Parameters
    ----------
    e_tot_j : ndarray, shape (n,) - cumulative energy [J]
    yield_pct : ndarray, shape (n,) - yield [%]
    method : {"continuous", "candidates"}
        "candidates" is the paper's method (breakpoints between data points, powder line + wax
        line + complete constant, least total SSE; each boundary reported at the midpoint of its
        gap). "continuous" fits a continuous powder-line / wax-line / plateau model whose two
        knots are profiled on a fine grid, so a boundary can fall between samples.
    n_boot : int - case-resampling bootstrap replicates for the uncertainty (0: none)
    random_state : int or Generator

    Returns
    -------
    BoundaryResult
    """
    e = np.asarray(e_tot_j, dtype=float)
    x = np.asarray(yield_pct, dtype=float)
    if e.shape != x.shape or e.ndim != 1 or not np.all(np.isfinite(e)) or not np.all(np.isfinite(x)):
        raise KineticsInputError("e_tot_j and yield_pct must be finite 1-d arrays of equal length")

    def one(ee, xx):
        if method == "candidates":
            e1, e2, sse, _, _ = _boundaries_candidates(ee, xx)
            return e1, e2, sse, None
        if method == "continuous":
            return _boundaries_continuous(ee, xx)
        raise KineticsInputError(f"unknown boundary method {method!r}")

    e1, e2, sse, coef = one(e, x)
    params = {"powder_wax_j": e1, "wax_complete_j": e2}
    resid = np.empty(0)
    if coef is not None:
        b, a, s = coef
        params.update(b_pct=b, a_pct_per_j=a, wax_slope_pct_per_j=s,
                      complete_level_pct=b + a * e1 + s * (e2 - e1))
        resid = x - _hinge_basis(e, [e1], [e2])[0] @ coef
    rng = np.random.default_rng(random_state)
    boot = []
    for _ in range(int(n_boot)):
        idx = rng.integers(0, e.size, e.size)
        try:
            b1, b2, _, _ = one(e[idx], x[idx])
        except KineticsInputError:
            continue
        boot.append((b1, b2))
    boot = np.asarray(boot, dtype=float).reshape(-1, 2)
    if boot.shape[0] >= 10:
        q = np.quantile(boot, [alpha / 2, 1 - alpha / 2], axis=0)
        ci = pd.DataFrame({"lower": q[0], "upper": q[1]}, index=["powder_wax_j", "wax_complete_j"])
    else:
        ci = pd.DataFrame({"lower": [np.nan] * 2, "upper": [np.nan] * 2},
                          index=["powder_wax_j", "wax_complete_j"])
    return BoundaryResult(method=method, params=pd.Series(params), ci=ci, boot=boot, sse=sse,
                          residuals=resid)


def _label_boundary(e, later):
    """One boundary from binary labels: gap between the last 'before' and first 'after' sample,
    or, where labels overlap, the 50 % point of a logistic fit (delta-method 95 % interval)."""
    before, after = e[~later], e[later]
    if before.size == 0 or after.size == 0:
        return np.nan, np.nan, np.nan
    if before.max() < after.min():
        return 0.5 * (before.max() + after.min()), before.max(), after.min()
    import statsmodels.api as sm
    ek = e / 1e3
    res = sm.Logit(later.astype(float), sm.add_constant(ek)).fit(disp=0)
    b0, b1 = res.params
    e50 = -b0 / b1
    g = np.array([-1.0 / b1, b0 / b1 ** 2])
    se = float(np.sqrt(g @ np.asarray(res.cov_params()) @ g))
    return e50 * 1e3, (e50 - 1.96 * se) * 1e3, (e50 + 1.96 * se) * 1e3


def boundaries_from_phase(e_tot_j, phase) -> BoundaryResult:
    """Boundaries from recorded phase labels ('powder', 'wax', 'complete').

    The interval of each boundary is the gap between the highest-energy sample of the earlier
    phase and the lowest-energy sample of the later one (estimate: its midpoint); where labels
    overlap in energy a logistic regression gives the 50 % point and its 95 % interval.
    """
    e = np.asarray(e_tot_j, dtype=float)
    ph = np.asarray([str(p).strip().lower() for p in phase])
    known = np.isin(ph, REGIMES)
    if known.sum() < 2:
        raise KineticsInputError("phase column has fewer than 2 labelled samples")
    e, ph = e[known], ph[known]
    pw = _label_boundary(e, ph != "powder")
    wc = _label_boundary(e, ph == "complete")
    params = pd.Series({"powder_wax_j": pw[0], "wax_complete_j": wc[0]})
    ci = pd.DataFrame({"lower": [pw[1], wc[1]], "upper": [pw[2], wc[2]]},
                      index=["powder_wax_j", "wax_complete_j"])
    return BoundaryResult(method="phase", params=params, ci=ci)
