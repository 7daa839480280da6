"""No reaction until the powder has taken up an energy E_ind (kinetics effect).

Amorphisation, crack nucleation or the break-up of a passivating layer can delay the chemistry
until a dose of mechanical energy has been delivered:

    X = a * max(0, E_tot - E_ind)[kJ] + b,     E_tot = E_kin f_col t,

(a, b the powder line). E_ind = 0 is the base model; the yield is not clipped at 0 (nor is the
base line's: b < 0 in the paper's fit).
"""
import numpy as np

from effects import base

DECLARATION = {
    "name": "induction_period",
    "kind": "kinetics",
    "physics": "no reaction until E_tot > E_ind: X = a max(0, E_tot - E_ind) + b",
    "parameters": {
        "induction_energy_j": {"default": 300.0, "lower": 0.0, "upper": 1e4, "unit": "J",
                               "description": "cumulative energy E_ind before the reaction "
                                              "starts"},
    },
    "null": {"induction_energy_j": 0.0},
    "diagnose": {"order": 90, "param": "induction_energy_j", "s_max": 1500.0,
                 "unit": "J"},
    "references": [
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003",
        "Boldyreva E (2013) Chem Soc Rev 42, 7719 (induction periods in mechanochemistry)",
    ],
    "changes": "the energy fed to the powder line: E_tot -> max(0, E_tot - E_ind)",
}


def effective_energy_j(e_kin_j, f_col_hz, time_s, params):
    """E_eff = max(0, E_kin f_col t - E_ind) [J]."""
    e = base.nonnegative_array("e_kin_j", e_kin_j)
    f = base.nonnegative_array("f_col_hz", f_col_hz)
    t = base.nonnegative_array("time_s", time_s)
    return np.maximum(0.0, e * f * t - params["induction_energy_j"])


def modify_kinetics(e_kin_j, f_col_hz, time_s, slope_pct_per_kj, intercept_pct, params):
    """Yield [%]: X = a E_eff / 1000 + b (signature as impact_threshold.modify_kinetics)."""
    return slope_pct_per_kj * effective_energy_j(e_kin_j, f_col_hz, time_s, params) / 1e3 \
        + intercept_pct


class Effect(base.KineticsEffect):
    modify = staticmethod(modify_kinetics)
