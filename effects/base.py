"""Base class of a switchable physical effect (standard library only: YADE imports it too).

An effect module ``effects/<name>.py`` holds one ``DECLARATION`` dict and, for a DEM effect, a
subclass of :class:`Effect` named ``Effect`` whose hooks the scene calls (yade_scripts/mill.py);
a kinetics effect provides ``modify_kinetics`` instead, an observation effect (the
measurement chain) ``observed_factor`` (see effects/template.py and effects/README.md). Parameters are declared once, with units and physical bounds; the scene, the
kinetic model, the diagnosis and the hidden-effect generator all read that declaration.
"""
import functools


class _Declared(object):
    """An effect's declaration and its validated parameters (shared by both kinds)."""

    def __init__(self, declaration, params):
        self.declaration = declaration
        self.params = dict(params)

    @property
    def name(self):
        return self.declaration["name"]

    def describe(self):
        return {"name": self.name, "params": dict(self.params)}


class Effect(_Declared):
    """One switched-on DEM effect with validated parameters ``self.params`` (a dict).

    ``needs_lab_frame``: True for an effect that moves, tilts or deforms the jar (it works on
    ``twin.motion`` or the facets): the scene then runs in the lab frame. An effect that acts on
    the ball and its contacts only may run in the jar frame, where ``twin.motion`` is None, the
    facets never move and ``twin.jar_ids``' velocity is zero (a velocity relative to the jar
    is then the ball's own).

    Hooks (all optional; ``twin`` is the scene object of yade_scripts/mill.py: ``twin.cfg``,
    ``twin.ball_id``, ``twin.jar_ids``, ``twin.motion`` (HarmonicMotionEngine), ``twin.mass``,
    ``twin.r``, ``twin.dt``, ``twin.f_now``, ``twin.phase_at(t)``, ``twin.jar_x()``):

    - ``setup(twin)``: after the scene is built (engines exist, jar at rest, f set);
    - ``on_frequency(twin, f, phi, t)``: the jar's frequency was set to f with phase phi at time t
      (called during the ramp and once before setup);
    - ``on_event_start(twin, region, interactions, vn_in)``: a contact event with 'end+', 'end-'
      or 'cylinder' began (YADE interactions, normal approach speed [m/s]);
    - ``on_sample(twin, t)``: at every output frame;
    - ``on_interaction_start(twin, region, interaction, vn_in)``: the contact monitor first sees
      this ball-facet interaction within an event (also facets reached later in the event);
    - ``amplitude(cfg, a)``: the jar's half stroke [m] the scene drives, given the config and
      the half stroke so far (``amplitude_m``, or what an earlier effect made of it); called
      before the scene is built (stroke_drift).
    """


    needs_lab_frame = False

    def setup(self, twin):
        pass

    def on_frequency(self, twin, f, phi, t):
        pass

    def on_event_start(self, twin, region, interactions, vn_in):
        pass

    def on_sample(self, twin, t):
        pass

    def on_interaction_start(self, twin, region, interaction, vn_in):
        """A ball-facet interaction was first seen in an event of ``region`` (called for the
        interactions present at the event's start too, after on_event_start)."""
        pass

    def amplitude(self, cfg, a):
        """The half stroke [m] the scene drives (default: unchanged)."""
        return a


# ----------------------------------------------------------------------------------------------
# helpers for effects (standard library only; yade is imported inside the functions that need it)
# ----------------------------------------------------------------------------------------------
#: Thornton et al. (2013) eq. B6 polynomial, as used by YADE 2023.02a's
#: Ip2_FrictMat_FrictMat_MindlinPhys to turn ``en`` into MindlinPhys.betan (checked against YADE
#: to 1e-12 at en = 0.05 ... 0.99: tests/test_effects.py reads betan from a YADE scene)
_THORNTON_H = (-6.918798, -16.41105, 146.8049, -796.4559, 2928.711, -7206.864, 11494.29,
               -11342.18, 6276.757, -1489.915)
#: restitution range in which the B6 fit is used (YADE clips the same way)
E_MIN, E_MAX = 0.001, 0.999


def thornton_betan(e):
    """Normal damping ratio betan [-] that gives restitution ``e`` in YADE's Hertz-Mindlin law.

    Thornton, Cummins & Cleary (2013) Powder Technol. 233, 30-46, eq. B6 (end of contact when
    the normal force vanishes): beta = sqrt(1 / (1 - (1 + e)^2 exp(a(e))) - 1), a a 10-term
    polynomial. e >= 0.999 gives 0 (elastic); e is clipped below at 0.001.
    """
    import math
    e = float(e)
    if e >= E_MAX:
        return 0.0
    e = max(e, E_MIN)
    a = 0.0
    for h in reversed(_THORNTON_H):
        a = e * (h + a)
    return math.sqrt(1.0 / (1.0 - (1.0 + e) ** 2 * math.exp(a)) - 1.0)


def restitution_of_betan(betan, tol=1e-10):
    """Inverse of :func:`thornton_betan` (bisection; betan decreases with e) [-]."""
    if betan <= 0.0:
        return 1.0
    lo, hi = E_MIN, E_MAX
    if betan >= thornton_betan(lo):
        return lo
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if thornton_betan(mid) > betan:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def yade_restitution(twin, e_phys):
    """YADE's ``en`` for a physical restitution, with the scene's time-step compensation.

    The scene set en_yade so that one impact at its dt rebounds with cfg['restitution']; the same
    ratio en_yade / restitution is applied to ``e_phys`` (clipped to [0.001, 1])."""
    e0 = twin.cfg["restitution"]
    ratio = twin.en_yade / e0 if e0 > 0 else 1.0
    return min(1.0, max(E_MIN, e_phys * ratio))


def physical_restitution(twin, e_yade):
    """Inverse of :func:`yade_restitution`."""
    e0 = twin.cfg["restitution"]
    ratio = twin.en_yade / e0 if e0 > 0 else 1.0
    return e_yade / ratio


#: restitution an effect gave an interaction during the current step: (id1, id2) -> (iter, e)
_SET_THIS_STEP = {}


def current_restitution(twin, interaction):
    """The physical restitution the interaction's impact will have with its present damping.

    The value another effect set at this step (effects compose in on_event_start), else the
    scene's: the restitution MindlinPhys.betan stands for (Thornton B6 inverted, dt-compensated).
    """
    from yade import O
    got = _SET_THIS_STEP.get((interaction.id1, interaction.id2))
    if got is not None and got[0] == O.iter:
        return got[1]
    return physical_restitution(twin, restitution_of_betan(interaction.phys.betan))


def set_restitution(twin, interactions, e_phys, vn_in=None):
    """Give new ball-wall interactions the normal damping of restitution ``e_phys``.

    Only MindlinPhys.betan changes (betas, the tangential damping, keeps the scene's value); the
    law reads betan at every step, so the change acts from the next step on. The event is
    detected up to ~20 us (a tenth of the contact) after onset and a heavily damped contact
    dissipates a good part of its energy early, so given ``vn_in`` (the approach speed at onset)
    the betan for the rest of the contact is solved from the contact's own equation of motion
    (:func:`remaining_contact_betan`), at most :func:`stable_betan` (what the time step
    integrates); without it the Thornton value is set. Returns the betan.
    """
    from yade import O
    if not interactions:
        return None
    e_now = current_restitution(twin, interactions[0])
    beta = thornton_betan(yade_restitution(twin, e_phys))
    if vn_in is not None:
        beta = remaining_contact_betan(twin, interactions, vn_in, e_phys, e_now, beta)
        beta = min(beta, stable_betan(twin.mass, interactions[0].phys.kno, vn_in, O.dt))
    for i in interactions:
        i.phys.betan = beta
        _SET_THIS_STEP[(i.id1, i.id2)] = (O.iter, e_phys)
    return beta


_SQ158 = (15.0 / 8.0) ** 0.5


def elastic_overlap_m(mass_kg, kno, vn_in_m_s):
    """Deepest overlap of an undamped Hertz impact at approach speed ``vn_in_m_s`` [m]:
    (5/4 m v^2 / k_no)^(2/5)."""
    return (1.25 * mass_kg * vn_in_m_s * vn_in_m_s / kno) ** 0.4


def stable_betan(mass_kg, kno, vn_in_m_s, dt_s):
    """The largest normal damping ratio the scene's explicit step integrates as damping [-].

    YADE's step updates the velocity with the damping force at the present velocity:
    v+ = v (1 - 2 betan omega dt) from damping alone, omega = sqrt(k_n / m), k_n = 3/2 k_no
    delta^(1/2) largest at the elastic impact's deepest overlap at ``vn_in_m_s``. At
    betan = 1 / (2 omega dt) one step stops the approach; about 3x beyond it the step reverses
    the approach faster than it came and the contact makes energy (the ball leaves the jar).
    The impact rebounds with e ~ 0.003 at this betan: a restitution's floor the time step sets.
    """
    if vn_in_m_s <= 0.0 or kno <= 0.0 or dt_s <= 0.0:
        return float("inf")
    d_max = elastic_overlap_m(mass_kg, kno, vn_in_m_s)
    omega = (1.5 * kno * d_max ** 0.5 / mass_kg) ** 0.5
    return 0.5 / (omega * dt_s)


def hertz_exit_speed(x0, v0, betan, h=0.004):
    """Rebound speed of a damped Hertz contact, nondimensional, from a state inside the contact.

    Units: overlap X in delta_max of the elastic impact at the onset speed, time in
    delta_max / v_onset, so X'' = -max(0, 5/4 X^(3/2) + 2 betan sqrt(15/8) X^(1/4) X') (YADE's
    Law2_ScGeom_MindlinPhys_Mindlin: c_n = 2 betan sqrt(m k_n), k_n = 3/2 k_no x^(1/2), total
    normal force clipped at 0). From (X, X') = (0, 1) the result is the restitution; RK4.

    Parameters
    ----------
    x0, v0 : float - overlap [-] and overlap rate [-] (positive = approaching)
    betan : float - damping ratio [-]
    h : float - time step [-] (the elastic contact lasts 3.2)
    """
    c = 2.0 * betan * _SQ158

    def acc(x, v):
        if x <= 0.0:
            return 0.0
        f = 1.25 * x ** 1.5 + c * x ** 0.25 * v
        return -f if f > 0.0 else 0.0

    x, v = x0, v0
    for _ in range(200000):
        if x <= 0.0 and v <= 0.0:
            break
        k1x, k1v = v, acc(x, v)
        k2x, k2v = v + 0.5 * h * k1v, acc(x + 0.5 * h * k1x, v + 0.5 * h * k1v)
        k3x, k3v = v + 0.5 * h * k2v, acc(x + 0.5 * h * k2x, v + 0.5 * h * k2v)
        k4x, k4v = v + h * k3v, acc(x + h * k3x, v + h * k3v)
        x += h / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x)
        v += h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
    return -v


def remaining_contact_betan(twin, interactions, vn_in, e_target, e_now, beta_guess):
    """betan for the rest of a contact so that the whole impact rebounds with ``e_target``.

    Reads the deepest interaction's overlap, overlap rate, k_no and betan, scales them by the
    elastic impact at ``vn_in`` (hertz_exit_speed's units) and integrates the rest of the contact.
    The continuous equation differs from YADE's discrete one by O(dt), so it is calibrated on the
    known outcome: with the present betan the impact rebounds with ``e_now``; the new betan makes
    the continuous rebound e_cont(betan) = e_cont(betan_now) * e_target / e_now (secant steps on
    log betan, a few RK4 integrations of ~800 steps, ~5 ms). Falls back to ``beta_guess`` for
    grazing contacts (vn_in < 0.05 m/s), contacts already rebounding, or a target out of reach.
    """
    import math
    from yade import O
    if vn_in < 0.05 or e_now <= 0.0:
        return beta_guess
    live = [i for i in interactions if i.isReal and i.phys.kno > 0.0]
    if not live:
        return beta_guess
    i = max(live, key=lambda j: j.geom.penetrationDepth)
    ball = O.bodies[twin.ball_id].state
    other = i.id1 if i.id2 == twin.ball_id else i.id2
    wall = O.bodies[other].state
    cp = i.geom.contactPoint
    n = cp - ball.pos
    n = n / max(n.norm(), 1e-300)
    v_wall = wall.vel + wall.angVel.cross(cp - wall.pos)
    rate = (ball.vel - v_wall).dot(n)
    d_max = elastic_overlap_m(twin.mass, i.phys.kno, vn_in)
    x0, v0 = i.geom.penetrationDepth / d_max, rate / vn_in
    if v0 <= 0.05 or x0 <= 0.0:
        return beta_guess
    target = hertz_exit_speed(x0, v0, i.phys.betan) * e_target / e_now
    if target >= v0:
        return 0.0
    b0 = max(beta_guess, 1e-4)
    b1 = b0 * 1.05
    f0 = hertz_exit_speed(x0, v0, b0) - target
    f1 = f0
    for _ in range(10):
        f1 = hertz_exit_speed(x0, v0, b1) - target
        if abs(f1) < 1e-4 * target or f1 == f0:
            break
        lb = math.log(b1) - f1 * (math.log(b1) - math.log(b0)) / (f1 - f0)
        b0, f0, b1 = b1, f1, math.exp(max(min(lb, math.log(b1) + 2.0), math.log(b1) - 2.0))
    if not math.isfinite(b1) or abs(f1) > 0.01 * target:
        return beta_guess
    return b1


def insert_engine_after(existing, new):
    """Put engine ``new`` into O.engines right after the engine ``existing`` (same object)."""
    from yade import O
    engines = list(O.engines)
    for k, e in enumerate(engines):
        if e is existing or (e.label and e.label == existing.label
                             and type(e).__name__ == type(existing).__name__):
            engines.insert(k + 1, new)
            O.engines = engines
            return
    raise RuntimeError("engine %r is not in O.engines" % (existing,))


def replace_engine(existing, new):
    """Replace engine ``existing`` in O.engines by ``new`` (kept at the same position)."""
    from yade import O
    engines = list(O.engines)
    for k, e in enumerate(engines):
        if e is existing or _same_engine(e, existing):
            engines[k] = new
            O.engines = engines
            return
    raise RuntimeError("engine %r is not in O.engines" % (existing,))


def _same_engine(a, b):
    if type(a).__name__ != type(b).__name__:
        return False
    try:
        return a.dict() == b.dict()
    except Exception:  # pragma: no cover - engines without a comparable dict
        return False


def jar_kinematic_engine(twin):
    """The last kinematic engine (or CombinedKinematicEngine) in O.engines that moves the jar
    facets: it sets their velocity (YADE's kinematic engines reset the velocities of their bodies
    before applying their motion), so it is the one to combine with."""
    from yade import O
    jar = set(twin.jar_ids)
    found = None
    for e in O.engines:
        kinds = [c.__name__ for c in type(e).__mro__]
        if ("KinematicEngine" in kinds or "CombinedKinematicEngine" in kinds) \
                and set(e.ids) == jar:
            found = e
    if found is None:
        raise RuntimeError("no kinematic engine moves the jar facets")
    return found


def python_runner(obj, method, iter_period, key):
    """A PyRunner calling ``obj.method()`` every ``iter_period`` steps.

    PyRunner commands run in ``__main__``; the object is published there as ``_EFFECT_<key>``."""
    import __main__
    from yade import PyRunner
    name = "_EFFECT_" + key
    setattr(__main__, name, obj)
    return PyRunner(iterPeriod=int(iter_period), command="%s.%s()" % (name, method),
                    label="effect_" + key)


class KineticsEffect(_Declared):
    """One switched-on kinetics effect: binds the module's ``modify_kinetics`` to its params.

    ``load_effects(spec, side='kinetics')`` returns these; ``effect.yield_pct(e_kin_j, f_col_hz,
    time_s, slope_pct_per_kj, intercept_pct)`` is the yield [%] with the effect.
    """
    modify = None  # staticmethod(the module's modify_kinetics), set by the subclass


    def yield_pct(self, e_kin_j, f_col_hz, time_s, slope_pct_per_kj, intercept_pct):
        return self.modify(e_kin_j, f_col_hz, time_s, slope_pct_per_kj, intercept_pct,
                                 self.params)


class ObservationEffect(_Declared):
    """One switched-on observation effect: the measurement chain, not the mill. Binds the
    module's ``observed_factor(observable, f_col_hz, params)`` to its params.

    ``load_effects(spec, side='observation')`` returns these; ``effect.factor_of(observable,
    f_col_hz)`` is the factor [-] (broadcast to ``f_col_hz``, the twin's collision rate per
    condition) by which the measurement chain reports the twin's true ``observable``. The twin
    and the chemistry (which sees the true speed) are unchanged: no run is made for it.

    A factor that needs more of the twin's state at each condition than its collision rate
    declares it as keyword arguments of its ``observed_factor`` (e.g. ``v_mean_m_s=None``,
    ``vy_rms_m_s=None``); ``factor_of(observable, f_col_hz, **state)`` passes on only the
    keywords the function names (all of them to a ``**kwargs``), so a factor of
    ``(observable, f_col_hz, params)`` alone keeps working. The state the loop's emulator
    passes (analysis.emulated_twin.EmulatedTwin._observed), each an array per condition:
    ``v_mean_m_s`` (the twin's mean speed in the dataset's frame), ``frequency_hz``,
    ``ball_diameter_m`` and, with jar tracks, the impact observables (``e_app``,
    ``v_in_m_s``, ``impact_phase_rad``, ``jar_amplitude_m``, ``vy_rms_m_s``); a keyword it
    does not get is None (the factor then assumes what its module says, or raises).
    """
    factor = None  # staticmethod(the module's observed_factor), set by the subclass

    def factor_of(self, observable, f_col_hz, **state):
        import numpy as np
        f = np.asarray(f_col_hz, dtype=float)
        kw = accepted_keywords(self.factor, state)
        return np.broadcast_to(np.asarray(self.factor(observable, f, self.params, **kw), float),
                               f.shape)


def accepted_keywords(fn, kwargs):
    """The items of ``kwargs`` that ``fn`` accepts by name (all of them if it takes
    ``**kwargs``)."""
    names = _keyword_names(fn)
    if names is None:
        return dict(kwargs)
    return {k: v for k, v in kwargs.items() if k in names}


@functools.lru_cache(maxsize=None)
def _keyword_names(fn):
    """The names ``fn`` takes by keyword (None: any, a ``**kwargs``), read once per function
    (a fit asks for an observation effect's factor at every point)."""
    import inspect
    params = inspect.signature(fn).parameters.values()
    if any(p.kind == p.VAR_KEYWORD for p in params):
        return None
    return frozenset(p.name for p in params
                     if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY))


def nonnegative_array(name, x):
    """``x`` as a float ndarray; ValueError naming ``name`` if any value is NaN, infinite or < 0."""
    import numpy as np
    a = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(a)):
        raise ValueError("%s must be finite, got %r" % (name, x))
    if np.any(a < 0):
        raise ValueError("%s must be >= 0, got %r" % (name, x))
    return a
