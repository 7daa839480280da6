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

