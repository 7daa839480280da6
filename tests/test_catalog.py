"""The diagnose catalog (analysis.catalog), built from the effect files' declarations: the
declared table and the strength coordinates."""
import pytest

from analysis import catalog

#: the diagnose catalog as it was declared before the effect files declared it
#: (name, kind, param, s_max, unit, coord, p0), in order: a change here
#: changes run ids, the emulator's inputs and every plot - make it on purpose
EXPECTED_CANDIDATES = [
    ("viscoelastic_restitution", "dem", "k", 0.6, "-", "linear", 1.0),
    ("arc_motion", "dem", "curvature_1_m", 15.0, "1/m", "linear", 1.0),
    ("jar_compliance", "dem", "f_n_hz", 1.5, "Hz", "inv_square", 100.0),
    ("powder_layer", "dem", "layer_thickness_m", 1.0, "m", "square", 5e-4),
    ("rolling_resistance", "dem", "extra_rolling_friction", 2.0, "-", "linear", 1.0),
    ("air_drag", "dem", "drag_scale", 1.0, "-", "linear", 1.0),
    ("impact_threshold", "kinetics", "threshold_energy_j", 0.04, "J", "linear", 1.0),
    ("first_order_depletion", "kinetics", "depletion", 1.0, "-", "linear", 1.0),
    ("induction_period", "kinetics", "induction_energy_j", 1500.0, "J", "linear", 1.0),
    ("temperature_rise", "kinetics", "thermal_resistance_k_w", 1.0, "K/W", "linear", 1.0),
]
EXPECTED_OPTIONAL = [
    ("end_fillet", "dem", "extra_fillet_m", 0.006, "m", "linear", 1.0),
    ("stroke_drift", "dem", "fall_per_hz", 0.015, "1/Hz", "linear", 1.0),
    ("apparent_scale", "observation", "blur_fraction", 0.1, "-", "linear", 1.0),
    ("smoothing_window", "observation", "window_s", 0.006, "s", "linear", 1.0),
    ("frame_rate", "observation", "frame_interval_s", 0.002, "s", "linear", 1.0),
    ("camera_plane", "observation", "tilt_rad", 1.0, "rad", "square", 0.2),
    ("collision_count", "observation", "flip_noise_m_s", 1.5, "m/s", "linear", 1.0),
]


def test_catalog_built_from_the_effect_files_is_the_declared_table():
    def rows(cands):
        return [(c.name, c.kind, c.param, c.s_max, c.unit, c.coord, c.p0) for c in cands]
    assert rows(catalog.CANDIDATES) == EXPECTED_CANDIDATES
    assert rows(catalog.OPTIONAL_CANDIDATES) == EXPECTED_OPTIONAL
    for c in catalog.CANDIDATES + catalog.OPTIONAL_CANDIDATES:
        assert c.fixed == () and isinstance(c.s_max, float) and isinstance(c.p0, float)
    assert catalog.DECOYS == ("air_drag",)
    assert list(catalog.candidates()) == [r[0] for r in EXPECTED_CANDIDATES + EXPECTED_OPTIONAL]


def test_strength_coordinates_round_trip():
    for c in catalog.CANDIDATES:
        s = 0.37 * c.s_max
        assert c.strength_of(c.param_value(s)) == pytest.approx(s, rel=1e-12)
    jc = catalog.candidates()["jar_compliance"]
    assert jc.param_value(1.0) == pytest.approx(100.0)
    import effects
    for c in catalog.CANDIDATES:   # the top of every range is inside the catalog's bounds
        effects.validate(c.name, c.spec(c.s_max)[c.name])
