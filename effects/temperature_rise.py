"""The jar warms up with the power the ball dissipates and the reaction speeds up (Arrhenius).

The ball delivers P = E_kin f_col [W], dissipated in the jar; the jar's temperature rises to a
steady excess dT_max = R_th P (R_th the jar's thermal resistance to the room) with time constant
tau:

    T(t) = T0 + R_th P (1 - exp(-t / tau)),
    F(t) = exp(Ea / R (1 / T0 - 1 / T(t))),             (Arrhenius factor, 1 at T0)
    E_eff(t) = P * integral_0^t F dt',      X = a E_eff[kJ] + b.

So hotter (faster, heavier-ball) conditions react more per joule, and long runs more than short
ones. R_th = 0 (or Ea = 0) is the base model. The integral is evaluated with the trapezoid rule
on 2001 points (relative error < 1e-6 for tau >= t / 100).
"""
import numpy as np

from effects import base

GAS_CONSTANT_J_MOL_K = 8.314462618
N_QUAD = 2001

DECLARATION = {
    "name": "temperature_rise",
    "kind": "kinetics",
    "physics": "jar temperature T = T0 + R_th P (1 - exp(-t/tau)) with P = E_kin f_col speeds "
               "the reaction by exp(Ea/R (1/T0 - 1/T))",
    "parameters": {
        "thermal_resistance_k_w": {"default": 2.0, "lower": 0.0, "upper": 50.0, "unit": "K/W",
                                   "description": "steady jar temperature rise per watt "
                                                  "dissipated"},
        "tau_s": {"default": 300.0, "lower": 1.0, "upper": 1e5, "unit": "s",
                  "description": "thermal time constant of the jar"},
        "activation_energy_j_mol": {"default": 60e3, "lower": 0.0, "upper": 300e3,
                                    "unit": "J/mol", "description": "Arrhenius activation energy"},
        "t0_k": {"default": 298.15, "lower": 250.0, "upper": 400.0, "unit": "K",
                 "description": "room (initial jar) temperature"},
    },
    "null": {"thermal_resistance_k_w": 0.0},
    "diagnose": {"order": 100, "param": "thermal_resistance_k_w", "s_max": 1.0,
                 "unit": "K/W"},
    "references": [
        "Anglou et al. (2024) ACS Sustain Chem Eng 12, 9003",
        "Kulla H et al. (2017) Chem Commun 53, 1664 (temperature rise in a vibratory ball mill)",
    ],
    "changes": "the energy fed to the powder line: E_tot -> P integral of the Arrhenius factor",
}


def temperature_k(time_s, power_w, params):
    """Jar temperature T(t) [K] (arrays broadcast)."""
    return params["t0_k"] + params["thermal_resistance_k_w"] * power_w * -np.expm1(
        -np.asarray(time_s, float) / params["tau_s"])


def arrhenius_factor(temperature, params):
    """exp(Ea/R (1/T0 - 1/T)) [-]."""
    return np.exp(params["activation_energy_j_mol"] / GAS_CONSTANT_J_MOL_K
                  * (1.0 / params["t0_k"] - 1.0 / temperature))


def effective_energy_j(e_kin_j, f_col_hz, time_s, params):
    """E_eff(t) = P * integral_0^t F(t') dt' [J], P = E_kin f_col (arrays broadcast)."""
    e = base.nonnegative_array("e_kin_j", e_kin_j)
    f = base.nonnegative_array("f_col_hz", f_col_hz)
    t = base.nonnegative_array("time_s", time_s)
    p, t = np.broadcast_arrays(e * f, t)
    u = np.linspace(0.0, 1.0, N_QUAD).reshape((N_QUAD,) + (1,) * t.ndim)
    tt = u * t  # shape (N_QUAD, *t.shape)
    fac = arrhenius_factor(temperature_k(tt, p, params), params)
    integral = t * (0.5 * (fac[1:] + fac[:-1])).sum(axis=0) / (N_QUAD - 1)  # trapezoid rule
    return p * integral


def modify_kinetics(e_kin_j, f_col_hz, time_s, slope_pct_per_kj, intercept_pct, params):
    """Yield [%]: X = a E_eff / 1000 + b (signature as impact_threshold.modify_kinetics)."""
    return slope_pct_per_kj * effective_energy_j(e_kin_j, f_col_hz, time_s, params) / 1e3 \
        + intercept_pct


class Effect(base.KineticsEffect):
    modify = staticmethod(modify_kinetics)
