"""The open model's base responses across a motion-mode jump (a bifurcation between the anchor
and a response level): the mean and sd it states must cover a step at an unknown place as
often as they claim, and the smooth side must not be bent by the jumped level."""
import numpy as np

from analysis.open_model import _jump_var, _poly_response, _response


def _pt(jump_lo=False, jump_hi=False, d_lo=-1.0, d_hi=0.3):
    xs = np.array([-0.06, 0.0, 0.06])
    ds = np.array([[d_lo, 2.0 * d_lo], [0.0, 0.0], [d_hi, 0.5 * d_hi]])
    return xs, ds, np.array([jump_lo, False, jump_hi])


def test_no_jump_is_the_quadratic():
    pt = _pt()
    for dx in (-0.09, -0.03, 0.0, 0.02, 0.08):
        assert np.allclose(_response(pt, pt[1], dx), _poly_response(pt[0], pt[1], dx))
        assert _jump_var(pt, dx) == 0.0


def test_jump_side_is_linear_then_flat_and_other_side_a_line():
    pt = _pt(jump_lo=True)
    xs, ds, _ = pt
    assert np.allclose(_response(pt, ds, -0.03), 0.5 * ds[0])
    assert np.allclose(_response(pt, ds, -0.12), ds[0])          # the jump has happened
    assert np.allclose(_response(pt, ds, 0.03), 0.5 * ds[2])     # a line, not the quadratic
    assert np.allclose(_jump_var(pt, -0.03), ds[0] ** 2 * 0.25)
    assert np.all(_jump_var(pt, -0.12) == 0.0)
    assert np.all(_jump_var(pt, 0.03) == 0.0)
    # weights of the points (the model_se path): linear in the changes
    w = _response(pt, np.eye(3), -0.03)
    assert np.allclose(w, [0.5, 0.0, 0.0])


def test_jump_sd_covers_a_step_at_an_unknown_place():
    """Truth: the response is 0 up to a step at a place drawn uniformly between the anchor and
    the level, then D. Over many draws and offsets the stated (mean, sd) must give z^2 with
    mean 1 and |z| <= 1.96 in about 95 % (a two-point distribution: checked on its own
    terms, the mean of z^2)."""
    rng = np.random.default_rng(7)
    pt = _pt(jump_lo=True, d_lo=-10.0)
    z2 = []
    for _ in range(4000):
        step = -0.06 * rng.uniform()
        dx = -0.06 * rng.uniform(0.05, 0.95)
        truth = -10.0 if dx <= step else 0.0
        mean = _response(pt, pt[1], dx)[0]
        sd = np.sqrt(_jump_var(pt, dx)[0])
        z2.append(((truth - mean) / sd) ** 2)
    assert abs(np.mean(z2) - 1.0) < 0.1
