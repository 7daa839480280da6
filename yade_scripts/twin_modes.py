"""Which steady motion a run is in (numpy only; shared by the YADE scene and analysis/).

One ball in this jar has several steady motions (see DESIGN.md). The classifier works on the
recorded window:

- ``end_to_end``: flight from end to end, close to two end impacts per jar cycle that alternate
  between the two ends (what the paper measured: f_col = 2 f);
- ``chatter``: end impacts that do not alternate (the ball rattles against one end), or more
  than 2.5 end impacts per cycle;
- ``rolling``: the ball rides the cylinder wall (in contact more than half the time) with few end
  impacts;
- ``slow``: mean speed below 0.5 m/s (DESIGN.md: a ball started at rest with C_R = 0.11 can land
  there);
- ``irregular``: none of the above.
"""
import numpy as np

SLOW_SPEED_M_S = 0.5


#: the motion modes :func:`classify_motion` names (a recording's ``summary.motion_mode``)
MOTION_MODES = ("end_to_end", "chatter", "rolling", "slow", "irregular")


def classify_motion(v_mean_m_s, frequency_hz, end_times_s, end_sides, duration_s,
                    cylinder_contact_fraction):
    """Name the motion of a recorded window.

    Parameters
    ----------
    v_mean_m_s : float - mean lab-frame ball speed over the window [m/s]
    frequency_hz : float - jar frequency [Hz]
    end_times_s : array, shape (n,) - start times of end-cap impacts [s]
    end_sides : array, shape (n,) - sign (+1/-1) of the end hit (jar-frame x of the contact)
    duration_s : float - length of the window [s]
    cylinder_contact_fraction : float - fraction of the window with a cylinder-wall contact

    Returns
    -------
    (mode, stats) : str and dict with end_impacts_per_cycle and alternation (fraction of
        consecutive end impacts that hit opposite ends).
    """
    n = len(end_times_s)
    cycles = max(duration_s * frequency_hz, 1e-12)
    per_cycle = n / cycles
    sides = np.sign(np.asarray(end_sides, dtype=float))
    alternation = float(np.mean(sides[1:] != sides[:-1])) if n > 1 else 0.0
    stats = {"end_impacts_per_cycle": float(per_cycle), "alternation": alternation,
             "cylinder_contact_fraction": float(cylinder_contact_fraction)}
    if v_mean_m_s < SLOW_SPEED_M_S:
        return "slow", stats
    if 1.5 <= per_cycle <= 2.5 and alternation >= 0.8:
        return "end_to_end", stats
    if per_cycle > 2.5 or (n > 1 and alternation < 0.5):
        return "chatter", stats
    if cylinder_contact_fraction > 0.5 and per_cycle < 1.5:
        return "rolling", stats
    return "irregular", stats


def collision_rate(times_s, duration_s, segments=None):
    """Collision rate from the impact times, not quantised by the record length.

    ``n / duration`` moves in steps of 1 / duration (2 /s in a 0.5 s record) and reads 56 /s for
    a ball that hits exactly 55 times a second. The rate here is the inverse mean interval
    between the first and the last impact, (n - 1) / (t_n - t_1): exact for a periodic sequence
    whatever the record length. Its standard error is that of a renewal process,
    rate * sd(intervals) / (mean interval * sqrt(n - 1)) - zero for a strictly periodic
    sequence, about rate / sqrt(n) for random (Poisson) impacts.

    Parameters
    ----------
    times_s : array, shape (n,) - impact times [s], any order
    duration_s : float - observed time of the record [s] (used only when fewer than 2
        intervals are seen)
    segments : array, shape (n,), optional - the stretch of unbroken observation each impact
        lies in (a track with lost frames): only intervals within one stretch are pooled, so an
        impact missed in a gap does not lengthen the mean interval

    Returns
    -------
    (rate_hz, se_hz) : floats. With fewer than 2 intervals the rate is n / duration and its
    standard error sqrt(max(n, 1)) / duration (a Poisson count).
    """
    t = np.asarray(times_s, dtype=float)
    seg = np.zeros(len(t)) if segments is None else np.asarray(segments, dtype=float)
    order = np.lexsort((t, seg))
    t, seg = t[order], seg[order]
    gaps = np.diff(t)[np.diff(seg) == 0]
    gaps = gaps[gaps > 0]
    n = len(t)
    if len(gaps) < 2:
        return (n / duration_s if duration_s > 0 else float("nan"),
                float(np.sqrt(max(n, 1)) / duration_s) if duration_s > 0 else float("nan"))
    mean_gap = float(gaps.mean())
    rate = 1.0 / mean_gap
    se = rate * float(gaps.std(ddof=1)) / (mean_gap * np.sqrt(len(gaps)))
    return float(rate), float(se)
