"""The twin as a model for :mod:`analysis.diagnose`: which catalog effect is missing?

The method is described in :mod:`analysis.twin_model.model`. The package, bottom to top (each
module imports only the ones above it in this list):

* :mod:`analysis.catalog` (outside the package: the one model of the twin reads it too) - the
  diagnose catalog: :class:`Candidate`, :data:`CANDIDATES`, :data:`DECOYS`,
  :data:`OPTIONAL_CANDIDATES`, :func:`candidates`, built from the effect files' declarations;
* :mod:`~analysis.twin_model.library` - the signature library: :func:`reference_parameters`,
  :func:`library_configs`, :func:`build_library`, :func:`refresh_flights`,
  :func:`load_library`, :func:`library_at`, the impact pattern rule :func:`in_late_pattern`;
* :mod:`~analysis.twin_model.model` - the model: the emulators, the signatures'
  interpolation, :class:`TwinModel` and diagnose's ``--model`` hook :func:`factory`;
* :mod:`~analysis.twin_model.cli` - the command line (``python -m analysis.twin_model``).

Every public name is re-exported here: import from ``analysis.twin_model``.

    python -m analysis.twin_model --build [--replicates 2] [--workers 2]   # the library
    python -m analysis.twin_model --flights      # impact observables of its cached runs
    python -m analysis.diagnose --dataset DIR --model analysis.twin_model:factory --out DIR
"""
from analysis.catalog import (CANDIDATES, DECOYS, OPTIONAL_CANDIDATES, SIGNATURE_LEVELS,
                              Candidate, candidates)
from analysis.twin_model.library import (CALIBRATION_DIR, DESIGN_FLIGHTS_FILE, LATE_V_IN_FRAC,
                                         SIGNATURE_DIR, add_flight_columns, build_library,
                                         design_flights, in_late_pattern, library_at,
                                         library_configs, load_library, plot_library,
                                         reference_parameters, refresh_flights, run_flights,
                                         summarise_library, top_level, write_page)
from analysis.twin_model.model import (BASE_BOUNDS, EM_PARAMS, F_COL_SD_FLOOR_HZ,
                                       FLIGHT_SD_FLOORS, OUTPUTS, STEEL_DENSITY_KG_M3,
                                       V_REL_SD_FLOOR, TwinModel, base_emulator, curvatures,
                                       dataset_observations, effect_levels, factory,
                                       flight_emulator, impact_patterns, interp_levels,
                                       interp_sd, with_run_sd, yield_times_of)
from analysis.twin_model.cli import main

#: The old private name of :func:`effect_levels` (tests use it).
_levels = effect_levels

__all__ = [
    "CANDIDATES", "DECOYS", "OPTIONAL_CANDIDATES", "SIGNATURE_LEVELS", "Candidate", "candidates",
    "CALIBRATION_DIR", "DESIGN_FLIGHTS_FILE", "LATE_V_IN_FRAC", "SIGNATURE_DIR",
    "add_flight_columns", "build_library", "design_flights", "in_late_pattern", "library_at",
    "library_configs", "load_library", "plot_library", "reference_parameters", "refresh_flights",
    "run_flights", "summarise_library", "top_level", "write_page",
    "BASE_BOUNDS", "EM_PARAMS", "F_COL_SD_FLOOR_HZ", "FLIGHT_SD_FLOORS", "OUTPUTS",
    "STEEL_DENSITY_KG_M3", "V_REL_SD_FLOOR", "TwinModel", "base_emulator", "curvatures",
    "dataset_observations", "effect_levels", "factory", "flight_emulator", "impact_patterns",
    "interp_levels", "interp_sd", "with_run_sd", "yield_times_of",
    "main",
]
