"""The reaction slows as the PET is used up (first-order in the remaining reactant).

The rate per unit energy falls with the converted fraction: dX/dE = a (1 - s (X - b)/100), with
a [%/kJ] the powder line's initial slope, b its intercept and s in [0, 1] the strength. Then

    X = b + (100 / s) (1 - exp(-s a E_tot[kJ] / 100)),

which starts on the linear line (slope a at E_tot = 0) and, at s = 1, saturates at 100 + b (the
classic X = 100 (1 - exp(-k E)) with k = a / 100 per kJ, shifted by the line's intercept). s = 0
is the base line X = a E_tot + b.
"""
import numpy as np

from effects import base

DECLARATION = {
    "name": "first_order_depletion",
    "kind": "kinetics",
    "physics": "rate proportional to the remaining PET: X = b + (100/s)(1 - exp(-s a E_tot/100))",
    "parameters": {
        "depletion": {"default": 1.0, "lower": 0.0, "upper": 1.0, "unit": "-",
                      "description": "s: 1 = first order in the remaining PET, 0 = linear"},
    },
    "null": {"depletion": 0.0},
    "diagnose": {"order": 80, "param": "depletion", "s_max": 1.0, "unit": "-"},
    "references": [
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003 (linear powder-regime line)",
        "Tan D, Friscic T (2018) Eur J Org Chem 2018, 18 (mechanochemical kinetics review)",
    ],
    "changes": "the yield's shape in E_tot: the straight line bends to saturation",
}


def modify_kinetics(e_kin_j, f_col_hz, time_s, slope_pct_per_kj, intercept_pct, params):
    """Yield [%] with depletion (signature as impact_threshold.modify_kinetics)."""
    e = base.nonnegative_array("e_kin_j", e_kin_j)
    f = base.nonnegative_array("f_col_hz", f_col_hz)
    t = base.nonnegative_array("time_s", time_s)
    e_kj = e * f * t / 1e3
    s = params["depletion"]
    if s < 1e-12:
        return slope_pct_per_kj * e_kj + intercept_pct
    return intercept_pct + 100.0 / s * -np.expm1(-s * slope_pct_per_kj * e_kj / 100.0)


class Effect(base.KineticsEffect):
    modify = staticmethod(modify_kinetics)
