"""The parameter space is declared once, and every reader sees that one declaration."""
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


def test_reference_parameters_are_the_calibrations_posterior_mean(tmp_path):
    """theta_ref: the Table-3 calibration's posterior mean (summary.json), rounded to 4
    significant digits; a missing calibration names the command that makes it."""
    import json
    from analysis.config import CALIBRATION_DIR
    ref = ps.reference_parameters()
    params = json.loads((CALIBRATION_DIR / "summary.json").read_text())["params"]
    assert set(ref) == set(params) >= {"restitution", "static_friction", "rolling_friction",
                                       "amplitude_m"}
    for k, v in params.items():
        assert ref[k] == float("%.4g" % v)
    (tmp_path / "summary.json").write_text(json.dumps({"params": {"restitution": 0.348712,
                                                                  "amplitude_m": 0.01273456}}))
    assert ps.reference_parameters(tmp_path) == {"restitution": 0.3487, "amplitude_m": 0.01273}
    with pytest.raises(FileNotFoundError, match="make calibrate"):
        ps.reference_parameters(tmp_path / "none")
