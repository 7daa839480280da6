"""The parameter space is declared once, and every reader sees that one declaration."""
import pandas as pd
import pytest

from analysis import parameter_space as ps
from yade_scripts.twin_config import PARAMETERS


def test_priors_lie_inside_the_run_configs_bounds_and_carry_its_units():
    for name, p in ps.SPACE.items():
        default, lo, hi, unit, role, _ = PARAMETERS[name]
        assert lo <= p.prior[0] < p.prior[1] <= hi
        assert p.unit == unit and p.role == role


def test_readers_share_the_declaration():
    from analysis import calibrate, sensitivity
    assert calibrate.CALIBRATED is ps.CALIBRATED and calibrate.PRIORS is ps.PRIORS
    for k, b in sensitivity.CONTACT_BOUNDS.items():
        assert b == ps.CALIBRATED[k]


def test_a_prior_outside_the_physical_bounds_is_refused(monkeypatch):
    monkeypatch.setitem(ps._DECLARED, "restitution", ((0.1, 1.5), True))
    with pytest.raises(ValueError, match="restitution"):
        ps._build()


def test_effect_strengths_come_from_the_effect_declarations():
    from analysis.catalog import CANDIDATES
    st = ps.effect_strengths()
    for c in CANDIDATES:
        assert st[c.name][:2] == (0.0, float(c.s_max))


def test_the_reference_point_lies_in_the_prior_box_at_four_digits():
    """theta_ref: the declared reference point (the base parameters, inside their priors, at
    4 significant digits so that run ids are stable); a copy, not the declaration."""
    ref = ps.reference_parameters()
    assert set(ref) == {p for p, q in ps.SPACE.items() if q.base}
    for k, v in ref.items():
        lo, hi = ps.SPACE[k].prior
        assert lo < v < hi and v == float("%.4g" % v)
    ref["restitution"] = 0.0
    assert ps.reference_parameters()["restitution"] == ps.REFERENCE["restitution"] > 0



def test_a_point_carries_the_declared_units_and_the_models_bounds():
    """ParameterVector: a mapping name -> float (what every predict takes) whose coordinates
    carry the unit the project declares and the bounds the model fits within; unknown names,
    non-numbers and NaN are refused with the name; it cannot be changed in place."""
    from analysis.diagnose import BaseParameter, Effect
    coords = ps.coordinates_of([BaseParameter("restitution", 0.3, 0.1, 0.7),
                                BaseParameter("amplitude_m", 0.0127, 0.011, 0.014),
                                BaseParameter("slope_pct_per_kj", 9.0, 1.0, 30.0)],
                               [Effect("arc_motion", 0.0, 15.0),
                                Effect("jar_compliance", 0.0, 1.5)])
    theta = ps.ParameterVector({"restitution": 0.3, "amplitude_m": 0.0127,
                                "slope_pct_per_kj": 9.0}, coords)
    assert [theta.unit(k) for k in theta] == ["-", "m", "%/kJ"]
    assert theta.bounds("amplitude_m") == (0.011, 0.014)      # the model's, a --free range
    assert coords["restitution"].kind == "contact" and coords["amplitude_m"].kind == "apparatus"
    added = ps.ParameterVector({"arc_motion": 12.5, "jar_compliance": 0.4}, coords)
    assert added.unit("arc_motion") == "1/m" and added.unit("jar_compliance") == "-"
    point = theta | added
    assert list(point) == ["restitution", "amplitude_m", "slope_pct_per_kj", "arc_motion",
                           "jar_compliance"]
    assert dict(point) == {**dict(theta), **dict(added)} and point.only(["arc_motion"]) == \
        {"arc_motion": 12.5}
    assert "amplitude_m 0.0127 [m]" in point.describe()
    assert ps.ParameterVector({"amplitude_m": 0.02}, coords).outside_bounds() == ["amplitude_m"]
    with pytest.raises(ValueError, match="friction_x"):
        ps.ParameterVector({"friction_x": 0.3}, coords)
    with pytest.raises(ValueError, match="restitution"):
        ps.ParameterVector({"restitution": float("nan")}, coords)
    with pytest.raises(ValueError, match="restitution"):
        ps.ParameterVector({"restitution": "high"}, coords)
    with pytest.raises(TypeError):
        theta["restitution"] = 0.5
    with pytest.raises(ValueError, match="bounds"):
        ps.Coordinate("x", "-", 1.0, 1.0, "model")


def test_the_emulators_powder_line_reads_its_bounds_from_the_one_declaration():
    """The kinetics line's coefficients are declared once (KINETICS_LINE): the model's base
    parameters with yields carry exactly those bounds."""
    from analysis.emulated_twin import EmulatedTwin
    from analysis.history_matching import DesignSpace
    cond = pd.DataFrame({"condition_id": ["a"], "frequency_hz": [25.0],
                         "ball_diameter_mm": [18.0]})
    m = EmulatedTwin(cond, DesignSpace.of(["restitution"], ()), yield_times_min={"a": [10.0, 20.0]})
    got = {p.name: (p.lower, p.upper) for p in m.base_params()}
    for k, (_, lo, hi) in ps.KINETICS_LINE.items():
        assert got[k] == (lo, hi)
