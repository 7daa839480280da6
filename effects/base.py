"""Base class of a switchable physical effect (standard library only: YADE imports it too).

An effect module ``effects/<name>.py`` holds one ``DECLARATION`` dict and, for a DEM effect, a
subclass of :class:`Effect` named ``Effect`` whose hooks the scene calls (yade_scripts/mill.py);
a kinetics effect provides ``modify_kinetics`` instead (see effects/template.py and
effects/README.md). Parameters are declared once, with units and physical bounds; the scene, the
kinetic model, the diagnosis and the hidden-effect generator all read that declaration.
"""


class Effect(object):
    """One switched-on DEM effect with validated parameters ``self.params`` (a dict).

    Hooks (all optional; ``twin`` is the scene object of yade_scripts/mill.py: ``twin.cfg``,
    ``twin.ball_id``, ``twin.jar_ids``, ``twin.motion`` (HarmonicMotionEngine), ``twin.mass``,
    ``twin.r``, ``twin.dt``, ``twin.f_now``, ``twin.phase_at(t)``, ``twin.jar_x()``):

    - ``setup(twin)``: after the scene is built (engines exist, jar at rest, f set);
    - ``on_frequency(twin, f, phi, t)``: the jar's frequency was set to f with phase phi at time t
      (called during the ramp and once before setup);
    - ``on_event_start(twin, region, interactions, vn_in)``: a contact event with 'end+', 'end-'
      or 'cylinder' began (YADE interactions, normal approach speed [m/s]);
    - ``on_sample(twin, t)``: at every output frame.
    """

    def __init__(self, declaration, params):
        self.declaration = declaration
        self.params = dict(params)

    @property
    def name(self):
        return self.declaration["name"]

    def describe(self):
        return {"name": self.name, "params": dict(self.params)}

    def setup(self, twin):
        pass

    def on_frequency(self, twin, f, phi, t):
        pass

    def on_event_start(self, twin, region, interactions, vn_in):
        pass

    def on_sample(self, twin, t):
        pass
