"""Kinetics: collision energy -> PET depolymerisation yield (paper Section 4, eq 4, Table 4).

The energy descriptor of a run is the cumulative kinetic energy delivered by the ball,

    E_tot(t) = E_kin * f_col * t,     E_kin = 1/2 m v_mean^2,   m = rho * pi d^3 / 6,

and the yield in the powder regime is the straight line X[%] = a * E_tot[kJ] + b (Table 4:
a = 9.49 +- 1.00 %/kJ, b = -3.03 +- 1.70 %). Above a powder-to-wax boundary (4593 J) the yield
rises steeply through a mixed powder/wax regime to complete depolymerisation above 7126 J.

The stage is split by job; every public name is re-exported here, so
``from analysis import kinetics`` / ``kinetics.fit_kinetics(...)`` keep working:

* :mod:`analysis.kinetics.model` - constants, :class:`KineticsInputError`, the energy
  descriptor (ball mass, E_kin, E_tot) and the powder line (OLS with 95 % confidence and
  prediction bands, statsmodels);
* :mod:`analysis.kinetics.energy_inputs` - E_kin and f_col per condition from the paper's
  Table 3 stand-in or a twin table, and E_tot per yield sample;
* :mod:`analysis.kinetics.boundaries` - the two regime boundaries found from the data with
  bootstrap uncertainty, or from phase labels;
* :mod:`analysis.kinetics.fitting` - :class:`KineticsFit` and :func:`fit_kinetics` (line +
  boundaries, saved as JSON);
* :mod:`analysis.kinetics.prediction` - regime, yield and bands for a new energy or condition;
* :mod:`analysis.kinetics.cli` - the command line; its figures are drawn by
  :mod:`analysis.plotting.kinetics_plots`::

    python -m analysis.kinetics [--yields DATASET] [--twin-table CSV] [--out DIR]

Until twin outputs exist the energy inputs come from the paper's Table 3 (measured v_mean of
the 17.5 and 20.6 mm balls, linearly interpolated in diameter to the 20 mm ball of the yield
experiments; f_col measured = 2 f). Every output says which source it used.

References
----------
Anglou et al., ACS Sustainable Chem. Eng. 2024, 12, 9003-9017, Section 4, eq 4, Table 4.
"""
from analysis.kinetics.model import (PAPER_INTERCEPT_PCT, PAPER_POWDER_WAX_J,
                                     PAPER_SLOPE_PCT_PER_KJ, PAPER_WAX_COMPLETE_J, REGIMES,
                                     STEEL_DENSITY_KG_M3, YIELD_BALL_DIAMETER_MM,
                                     KineticsInputError, LineFitResult, ball_mass_kg,
                                     cumulative_energy_j, fit_powder_line, kinetic_energy_j)
from analysis.kinetics.energy_inputs import (TABLE3_SOURCE_AS_IS, TABLE3_SOURCE_INTERP,
                                             attach_cumulative_energy, energy_for_conditions,
                                             load_twin_energy_table, table3_energy_inputs)
from analysis.kinetics.boundaries import BoundaryResult, boundaries_from_phase, find_boundaries
from analysis.kinetics.fitting import KineticsFit, fit_kinetics
from analysis.kinetics.prediction import (model_curves, predict_yield,
                                          predict_yield_from_energy, regime_of, yield_bands)
from analysis.kinetics.cli import main, run

__all__ = [
    "PAPER_INTERCEPT_PCT", "PAPER_POWDER_WAX_J", "PAPER_SLOPE_PCT_PER_KJ", "PAPER_WAX_COMPLETE_J",
    "REGIMES", "STEEL_DENSITY_KG_M3", "YIELD_BALL_DIAMETER_MM", "KineticsInputError",
    "LineFitResult", "ball_mass_kg", "cumulative_energy_j", "fit_powder_line",
    "kinetic_energy_j",
    "TABLE3_SOURCE_AS_IS", "TABLE3_SOURCE_INTERP", "attach_cumulative_energy",
    "energy_for_conditions", "load_twin_energy_table", "table3_energy_inputs",
    "BoundaryResult", "boundaries_from_phase", "find_boundaries",
    "KineticsFit", "fit_kinetics",
    "model_curves", "predict_yield", "predict_yield_from_energy", "regime_of", "yield_bands",
    "main", "run",
]
