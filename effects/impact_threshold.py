"""Only impacts above an energy threshold E* make the reaction go (kinetics effect).

Mechanochemical activation needs a minimum local stress: an impact with energy E below E* does
nothing, one above delivers E - E*. The reacting energy is the sum over impacts of
max(0, E_i - E*). With only the mean impact energy E_kin = 1/2 m v_mean^2 and the collision
frequency f_col known, every impact is taken to carry E_kin:

    E_eff(t) = f_col * t * max(0, E_kin - E*),     X = a * E_eff[kJ] + b,

(a, b the powder line's slope [%/kJ] and intercept [%]). With a spread of impact energies the
threshold would act smoothly; this is its sharpest form. E* = 0 is the base model.
"""
import numpy as np

from effects import base

DECLARATION = {
    "name": "impact_threshold",
    "kind": "kinetics",
    "physics": "only impact energy above E* reacts: E_eff = f_col t max(0, E_kin - E*)",
    "parameters": {
        "threshold_energy_j": {"default": 0.01, "lower": 0.0, "upper": 1.0, "unit": "J",
                               "description": "impact energy E* below which nothing reacts"},
    },
    "null": {"threshold_energy_j": 0.0},
    "diagnose": {"order": 70, "param": "threshold_energy_j", "s_max": 0.04,
                 "unit": "J"},
    "references": [
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003 (E_tot = E_kin f_col t)",
        "Delogu F, Takacs L (2018) J Mater Sci 53, 13331 (kinetics of mechanochemical "
        "reactions from impact statistics)",
    ],
    "changes": "the energy fed to the powder line: E_tot -> f_col t max(0, E_kin - E*)",
}


def effective_energy_j(e_kin_j, f_col_hz, time_s, params):
    """E_eff = f_col t max(0, E_kin - E*) [J] (arrays broadcast)."""
    e = base.nonnegative_array("e_kin_j", e_kin_j)
    f = base.nonnegative_array("f_col_hz", f_col_hz)
    t = base.nonnegative_array("time_s", time_s)
    return f * t * np.maximum(0.0, e - params["threshold_energy_j"])


def modify_kinetics(e_kin_j, f_col_hz, time_s, slope_pct_per_kj, intercept_pct, params):
    """Yield [%] with the threshold: X = a E_eff / 1000 + b.

    Parameters
    ----------
    e_kin_j : float or ndarray - mean impact energy E_kin [J]
    f_col_hz : float or ndarray - collision frequency [1/s]
    time_s : float or ndarray - milling time [s]
    slope_pct_per_kj, intercept_pct : float - the powder line X = a E[kJ] + b
    params : dict - {"threshold_energy_j": E*}

    Returns
    -------
    ndarray (broadcast shape) - yield [%]
    """
    return slope_pct_per_kj * effective_energy_j(e_kin_j, f_col_hz, time_s, params) / 1e3 \
        + intercept_pct


class Effect(base.KineticsEffect):
    modify = staticmethod(modify_kinetics)
