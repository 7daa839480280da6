"""Shared pieces of the convergence studies: the short mill protocol and replicate statistics."""
import numpy as np
import pandas as pd

#: a shorter protocol than the default, for studies that need many runs: 0.3 s ramp, >= 0.2 s
#: settle, 0.3 s record (v_mean of 20.6 mm at 25 Hz differs from the 0.5 s record by < its sd)
STUDY_PROTOCOL = {"ramp_s": 0.3, "settle_min_s": 0.2, "settle_max_s": 1.0, "record_s": 0.3}


def replicate_stats(table, by, cols=("v_mean_m_s", "f_col_hz")):
    """Mean, sd, standard error and count of ``cols`` per group of ``by`` (failed runs dropped).

    Returns
    -------
    DataFrame, one row per group: <col>_mean, <col>_sd, <col>_se, n, modes (the motion modes seen)
    """
    ok = table[table["status"].isin(["done", "cached"])]
    rows = []
    for key, g in ok.groupby(by):
        row = {by: key, "n": len(g)}
        for c in cols:
            x = g[c].astype(float).to_numpy()
            row[c + "_mean"] = float(np.mean(x))
            row[c + "_sd"] = float(np.std(x, ddof=1)) if len(x) > 1 else float("nan")
            row[c + "_se"] = row[c + "_sd"] / np.sqrt(len(x)) if len(x) > 1 else float("nan")
        row["modes"] = "/".join(sorted(set(g["motion_mode"].astype(str))))
        rows.append(row)
    return pd.DataFrame(rows)
