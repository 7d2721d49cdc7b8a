"""What a restoring force does after each reversal of the displacement: play or a smooth loop.

Play (backlash, a clearance) and hysteresis both make a loop in the force-displacement
plane; the data tell them apart after each reversal of the motion:

* play: the force drops to near zero at once and stays there while the clearance is
  crossed -- a plateau whose width (twice the half-width of the clearance) does not
  grow with the amplitude -- then engages at the level of the new direction;
* hysteresis: the force passes through zero on a smooth, steep curve (no plateau).

For the nonlinear part of the force ``r`` (the measured force minus a fitted
``m a + c v + k x``), each half-cycle between two reversals is read on the
displacement travelled since the reversal: ``q = s r / L`` (``s`` the new direction,
``L`` the level the force settles at in the last ``SETTLED`` of the half-cycle) goes
from about -1 to 1.  The force is read about its own centre: the midpoint of the levels
it settles at going up and going down (median over the half-cycles of each direction), so
a constant in the force -- a load cell's zero, a spring's force at a displaced centre --
is no part of the reading (with a constant as large as the friction, every half-cycle
passed through ``q = 0`` at a point and no plateau was read: a friction damper with play in
mm and kN with an offset of 2 std(force) read "a smooth loop", plateau fraction 0.0;
0.92 about the centre).  The *transition* is the travel until ``q`` first reaches
``ENGAGED``; the *plateau* the travel within it while ``|q| < NEAR_ZERO``.  A
half-cycle that settles below ``MIN_LEVEL`` of the record's sliding level (the 90th
percentile of the levels) is not read: it turned inside the clearance.  The
record shows play when the median plateau fraction is at least ``PLAY_FRACTION``
and, where the amplitudes differ by ``AMPLITUDE_SPREAD`` or more, the plateau widths
grow with the amplitude with an exponent below ``MAX_GROWTH`` (a smooth loop of a
Bouc-Wen law spends ~20 % of its transition near zero).
"""

import numpy as np

SETTLED = 0.3
ENGAGED = 0.75
NEAR_ZERO = 0.25
PLAY_FRACTION = 0.5
AMPLITUDE_SPREAD = 1.5
MAX_GROWTH = 0.5
#: A reversal needs an excursion of this fraction of the displacement's spread (std).
MIN_EXCURSION = 0.2
#: A half-cycle is read only if its settled level is at least this fraction of the
#: record's sliding level (the 90th percentile of the half-cycles' levels).
MIN_LEVEL = 0.5


def turning_points(x, min_excursion):
    """Return the indices of the reversals of ``x`` (excursions below ``min_excursion`` ignored)."""
    x = np.asarray(x, float)
    out = []
    i_ext, direction = 0, 0
    for i in range(1, x.size):
        d = x[i] - x[i_ext]
        if direction >= 0 and x[i] > x[i_ext] or direction <= 0 and x[i] < x[i_ext]:
            if direction == 0 and abs(d) < min_excursion:
                continue
            if direction == 0:
                direction = 1 if d > 0 else -1
            i_ext = i
        elif abs(d) >= min_excursion:
            out.append(i_ext)
            direction = -direction
            i_ext = i
    return np.array(out, int)


def centre(x, r, tp=None):
    """Return the centre of the force ``r``: the midpoint of its settled levels up and down.

    The level of a half-cycle is the median of ``r`` over its last ``SETTLED``; the
    centre is the midpoint of the median level of the rising and of the falling
    half-cycles (0 when the record has not both).
    """
    x, r = np.asarray(x, float), np.asarray(r, float)
    if tp is None:
        tp = turning_points(x, MIN_EXCURSION * float(np.std(x)))
    levels = {1.0: [], -1.0: []}
    for a, b in zip(tp[:-1], tp[1:], strict=True):
        n = b - a + 1
        if n < 8:
            continue
        s = 1.0 if x[b] > x[a] else -1.0
        levels[s].append(float(np.median(r[a + int((1 - SETTLED) * n):b + 1])))
    if not levels[1.0] or not levels[-1.0]:
        return 0.0
    return 0.5 * (float(np.median(levels[1.0])) + float(np.median(levels[-1.0])))


def half_cycles(x, r):
    """Return one row per half-cycle: amplitude, transition width, plateau width, fraction.

    ``r`` is read about its :func:`centre`; a half-cycle that settles below ``MIN_LEVEL``
    of the record's sliding level has no row.
    """
    x, r = np.asarray(x, float), np.asarray(r, float)
    tp = turning_points(x, MIN_EXCURSION * float(np.std(x)))
    r = r - centre(x, r, tp)
    rows = []
    for a, b in zip(tp[:-1], tp[1:], strict=True):
        s = 1.0 if x[b] > x[a] else -1.0
        seg_x, seg_r = x[a:b + 1], s * r[a:b + 1]
        n = seg_x.size
        level = float(np.median(seg_r[int((1 - SETTLED) * n):]))
        if n < 8 or level <= 0:
            continue
        q = seg_r / level
        up = np.flatnonzero(q >= ENGAGED)
        if up.size == 0:
            continue
        k = int(up[0])
        step = np.abs(np.diff(seg_x[:k + 1]))
        travel = float(np.sum(step))
        if travel <= 0:
            continue
        near = float(np.sum(step[np.abs(q[1:k + 1]) < NEAR_ZERO]))
        rows.append((0.5 * abs(x[b] - x[a]), travel, near, near / travel, level))
    rows = np.array(rows).reshape(-1, 5)
    if rows.shape[0]:
        # a reversal inside the clearance never engages: its level is noise, and so is
        # its plateau (a sweep whose held-out end turns within the clearance read a width
        # growing with the amplitude from such half-cycles on smoother states)
        rows = rows[rows[:, 4] >= MIN_LEVEL * np.percentile(rows[:, 4], 90)]
    return rows[:, :4]


def evidence(x, r):
    """Return the play-versus-loop evidence of a record (see the module doc) as a plain dict."""
    rows = half_cycles(x, r)
    if rows.shape[0] < 2:
        return {'half_cycles': int(rows.shape[0]), 'plateau_fraction': None, 'growth': None,
                'play': False, 'reading': 'too few reversals to read'}
    frac = float(np.median(rows[:, 3]))
    amp, width = rows[:, 0], rows[:, 2]
    growth = None
    ok = width > 0
    if ok.sum() >= 3 and amp[ok].max() >= AMPLITUDE_SPREAD * amp[ok].min():
        growth = float(np.polyfit(np.log(amp[ok]), np.log(width[ok]), 1)[0])
    play = frac >= PLAY_FRACTION and (growth is None or growth < MAX_GROWTH)
    reading = ('a near-zero-force plateau after each reversal: play' if play else
               'a smooth loop through zero force: hysteresis' if frac < PLAY_FRACTION else
               'a near-zero-force stretch that grows with the amplitude: not play')
    return {'half_cycles': int(rows.shape[0]), 'plateau_fraction': frac,
            'plateau_width_median': float(np.median(width)),
            'amplitude_range': [float(amp.min()), float(amp.max())],
            'growth': growth, 'play': bool(play), 'reading': reading}
