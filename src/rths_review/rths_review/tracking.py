"""The loop as the bag recorded it: steps per topic, their alignment, tracking and timing.

What every review of a run reads first, whatever its structure: each loop topic's steps
(:func:`step_check`, :func:`read_loop`), made whole for the spectral estimates
(:func:`aligned_steps`: re-sends dropped, gaps filled and accounted for,
:func:`recording_summary`), each actuator's target, command and measurement up to the
end or a safety stop (:func:`tracking_channels`), Table 5's delay and tracking error
(:func:`table5_of`, :func:`weighted_delay_ms`), the bridge's real-time figures
(:func:`bridge_realtime`) and an external controller's counts (:func:`controller_counts`).
:mod:`rths_review.review` (one actuator: Tables 5-9) and :mod:`rths_review.actuators`
(several) build on it.
"""

import numpy as np
from scipy import signal

from rths_common import bagio, topics
from rths_compensator.estimation import impulse_response
from rths_compensator.indicators import relative_rms_pct
from rths_review.realtime import realtime_figures

#: Loop topics that carry one message per step, and the array field to summarise.
STEP_TOPICS = {
    topics.INTERFACE_DISPLACEMENT: ('displacement', 'm'),
    topics.COMMAND: ('command', 'm'),
    topics.MEASUREMENT: ('force', 'N'),
}


def step_check(steps) -> dict:
    """Count, first/last step, gaps, duplicates and order of a step sequence."""
    steps = np.asarray(steps, dtype=np.int64)
    if steps.size == 0:
        return {'count': 0, 'first': None, 'last': None, 'gaps': 0, 'duplicates': 0,
                'in_order': True}
    diffs = np.diff(steps)
    unique = np.unique(steps)
    return {
        'count': int(steps.size),
        'first': int(steps[0]),
        'last': int(steps[-1]),
        'gaps': int(unique[-1] - unique[0] + 1 - unique.size),
        'duplicates': int(steps.size - unique.size),
        'in_order': bool(np.all(diffs > 0)),
    }


def read_loop(bag) -> dict:
    """Per-topic step indices and arrays of a bag: ``{topic: {'step': [...], field: [[...]]}}``.

    ``status``: per node its steps, timings, deadline misses, safety states, stamps
    and its faults (each once, ``step K: text`` of the first step reporting it).
    """
    data = {t: {'step': [], 'values': []} for t in STEP_TOPICS}
    status = {}
    for topic, _, msg in bagio.read_messages(bag, list(STEP_TOPICS) + [topics.STATUS]):
        if topic == topics.STATUS:
            s = status.setdefault(msg.node, {'step': [], 'compute_us': [], 'latency_us': [],
                                             'misses': 0, 'safety_state': [], 'faults': [],
                                             'stamp_ns': [], 'missed': []})
            s['step'].append(msg.step)
            s['stamp_ns'].append(msg.header.stamp.sec * 1_000_000_000
                                 + msg.header.stamp.nanosec)
            s['missed'].append(bool(msg.deadline_missed))
            s['compute_us'].append(msg.compute_us)
            s['latency_us'].append(msg.latency_us)
            s['misses'] = max(s['misses'], msg.deadline_misses)
            s['safety_state'].append(msg.safety_state)
            if msg.fault and msg.fault != s.get('last_fault'):   # each fault once, first step
                s['faults'].append(f'step {msg.step}: {msg.fault}')
                s['last_fault'] = msg.fault
            continue
        field, _ = STEP_TOPICS[topic]
        data[topic]['step'].append(msg.step)
        data[topic]['values'].append(np.asarray(getattr(msg, field), dtype=float))
    return {'steps': data, 'status': status}


#: Gaps listed one by one in summary.json (the rest are counted).
MAX_GAPS_LISTED = 20


def aligned_steps(data: dict, fields, fs_hz: float, where: str) -> tuple:
    """Make a topic's ``step_arrays`` whole: row i is step i, from step 0 to the last.

    A step recorded more than once with the same values is a re-send: the
    copies are dropped. A step missing from the recording is filled linearly
    from its neighbours (before the first recorded step: that step's values),
    however long the gap. Returns ``(arrays, info)``: ``info`` holds
    ``resent``, ``filled`` (steps), ``gaps`` (the number of gaps),
    ``longest_gap_steps``, ``gap_list`` (up to MAX_GAPS_LISTED
    ``{'first_step', 'steps', 'start_s'}``) and ``recorded`` (a bool per step).
    ValueError (naming ``where``) for an empty topic or conflicting copies.
    """
    steps = np.asarray(data['step'], dtype=np.int64)
    if steps.size == 0:
        raise ValueError(f'{where}: no messages recorded')
    last = int(steps.max())
    out, seen = {}, np.zeros(last + 1, dtype=bool)
    order = np.argsort(steps, kind='stable')
    first = np.ones(steps.size, dtype=bool)
    first[order[1:]] = steps[order[1:]] != steps[order[:-1]]
    for f in fields:
        values = np.asarray(data[f], dtype=float)
        table = np.full((last + 1, values.shape[1]), np.nan)
        table[steps[first]] = values[first]
        copies = values[~first]
        if not np.array_equal(copies, table[steps[~first]], equal_nan=True):
            k = int(steps[~first][0])
            raise ValueError(f'{where}: step {k} was recorded twice with different values; '
                             'two publishers on one topic? the run cannot be aligned')
        out[f] = table
    seen[steps] = True
    missing = np.flatnonzero(~seen)
    if missing.size:
        known = np.flatnonzero(seen)
        for f in fields:
            for col in out[f].T:            # a view: filled in place
                col[missing] = np.interp(missing, known, col[known])
    runs = gap_runs(missing)
    return out, {'resent': int((~first).sum()), 'filled': int(missing.size),
                 'gaps': len(runs), 'longest_gap_steps': max((n for _, n in runs), default=0),
                 'gap_list': [{'first_step': k, 'steps': n, 'start_s': round(k / fs_hz, 4)}
                              for k, n in runs[:MAX_GAPS_LISTED]],
                 'recorded': seen}


def gap_runs(index) -> list:
    """Return ``[(first, length)]`` of the runs of consecutive integers in sorted ``index``."""
    index = np.asarray(index, dtype=np.int64)
    if index.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(index) != 1)
    starts = np.r_[0, breaks + 1]
    ends = np.r_[breaks, index.size - 1]
    return [(int(index[a]), int(b - a + 1)) for a, b in zip(starts, ends, strict=True)]


#: Upper edge [Hz] of the band over which delays are averaged (the seed's RTHS design band).
DELAY_BAND_HZ = 10.0


#: Counts of an external controller in ``summary['controller']`` (rths_msgs/ControllerStatus).
CONTROLLER_KEYS = ('replies_lost', 'replies_late', 'replies_malformed', 'restarts',
                   'worst_reply_ms', 'replies', 'replies_duplicate', 'replies_out_of_order',
                   'datagrams_foreign', 'protocol_version', 'address', 'fault')


def controller_counts(bag):
    """Return the last ``/rths/controller`` counts of a bag as a dict, or None if none."""
    last = None
    for _, _, msg in bagio.read_messages(bag, [topics.CONTROLLER]):
        last = msg
    if last is None:
        return None
    out = {key: getattr(last, key) for key in CONTROLLER_KEYS}
    out['worst_reply_ms'] = round(float(out['worst_reply_ms']), 3)
    return {k: (int(v) if isinstance(v, (int, np.integer)) else v) for k, v in out.items()}


class TooShortError(ValueError):
    """A run recorded under 2 s before its end or a safety stop: too short for tables 5-9."""


def weighted_delay_ms(desired, measured, fs_hz, band_hz=DELAY_BAND_HZ,
                      memory_s: float = 0.5) -> float:
    """Eq. 42 delay from time series, averaged over ``0 < f <= band_hz`` weighted by the PSD.

    The seed averages eq. 42 over the input bandwidth of a BLWN (flat spectrum).
    An RTHS response is narrow-band (most energy near the building's first
    mode); weighting each Welch bin by the desired signal's power gives the
    delay the loop actually experiences and equals the plain average for a flat
    spectrum.  The frequency response is that of the record's impulse response
    (least squares on the lagged inputs, ``memory_s`` long:
    :func:`rths_compensator.estimation.impulse_response`), not a Welch H1
    estimate: at the 1-2 Hz of a building's mode a phase error of 0.01 rad is
    1 ms, and the H1 estimate's leakage across its 4 s segments was of that
    order (13.93 ms where the plant's own weighted phase delay is 14.74 ms;
    the impulse response gives 14.74 ms).
    """
    d = np.asarray(desired, dtype=float)
    nperseg = int(min(d.size, 4 * round(fs_hz)))
    f, pdd = signal.welch(d, fs=fs_hz, nperseg=nperseg)
    sel = (f > 0) & (f <= band_hz)
    if np.count_nonzero(sel) < 2:
        raise ValueError(f'too few frequency bins in 0-{band_hz} Hz to estimate a delay')
    n_lags = int(max(8, min(round(memory_s * fs_hz), d.size // 4)))
    h = impulse_response(d, measured, n_lags)
    _, frf = signal.freqz(h, [1.0], worN=f[sel], fs=fs_hz)
    phase = np.angle(frf)  # the delay is far below half a period here: no unwrapping
    tau = -phase / (2 * np.pi * f[sel])
    return float(np.sum(tau * pdd[sel]) / np.sum(pdd[sel]) * 1e3)


def tracking_channels(bag, fs, channels: int | None = None):
    """Return desired, applied (shifted by the delay line), measured up to a safety trip.

    Each is (steps x N), one column per actuator: the first ``channels`` (default every
    one the bag's measurements hold); a step counts only when every one of them has a
    finite command and measurement.  Also the measurement arrays, the bridge's status,
    the step count ``n``, the bridge ticks recorded, the repairs of the recording
    (:func:`aligned_steps`) and ``kept``: per step of the ``n``, True if both its
    interface displacement and its measurement are in the bag (not filled).
    :class:`TooShortError` if the bag holds under 2 s before its end or a safety stop.
    """
    recording, series = {}, {}
    for topic, fields in ((topics.INTERFACE_DISPLACEMENT, ('displacement',)),
                          (topics.MEASUREMENT, ('applied', 'displacement', 'force'))):
        series[topic], recording[topic] = aligned_steps(
            bagio.step_arrays(bag, topic, fields), fields, fs, f'{bag}: {topic}')
    disp, meas = series[topics.INTERFACE_DISPLACEMENT], series[topics.MEASUREMENT]
    recorded = len(meas['force'])                   # bridge ticks in the bag
    n = int(min(len(disp['displacement']), recorded))
    width = channels or min(disp['displacement'].shape[1], meas['applied'].shape[1])
    desired = disp['displacement'][:n, :width]
    applied = meas['applied'][:, :width]
    shift = bagio.delay_steps(bag)  # the command of step k was written at tick k + D
    applied = np.concatenate([applied[shift:], np.full((shift, width), np.nan)])[:n]
    measured = meas['displacement'][:n, :width]
    ok = np.all(np.isfinite(applied) & np.isfinite(measured), axis=1)
    status = read_loop(bag)['status'].get('bridge', {})
    tripped = [k for k, state in zip(status.get('step', []), status.get('safety_state', []),
                                     strict=False) if state != 0]
    if tripped and min(tripped) < n:  # a safety stop: review what ran before the fault
        ok[int(min(tripped)):] = False  # (then the plant holds and ramps to the safe position)
    if not ok.all():
        n = int(np.argmin(ok))
        desired, applied, measured = desired[:n], applied[:n], measured[:n]
    if n < 2 * fs:
        raise TooShortError(f'{bag}: only {n} steps recorded before the end or a safety stop; '
                            'the review needs at least 2 s')
    kept = (recording[topics.INTERFACE_DISPLACEMENT].pop('recorded')[:n]
            & recording[topics.MEASUREMENT].pop('recorded')[:n])
    return desired, applied, measured, meas, status, n, recorded, recording, kept


def table5_of(desired, applied, measured, fs, kept=None) -> dict:
    """Return table 5: delay and tracking of the plant (command) and the compensated actuator.

    ``kept``: the steps the recording holds (True) and those filled in its gaps;
    the tracking errors are computed on the kept steps only, the delays (a
    spectral estimate that needs an unbroken series) on the whole, gaps filled.
    """
    # Table 5: the plant (command -> measured; with D > 0 it includes the D-step delay line)
    # and the compensated actuator (desired -> measured)
    k = slice(None) if kept is None else np.asarray(kept, dtype=bool)
    return {
        'delay_ms_before': weighted_delay_ms(applied, measured, fs),
        'delay_ms_after': weighted_delay_ms(desired, measured, fs),
        'tracking_rel_rms_pct_before': relative_rms_pct(applied[k], measured[k]),
        'tracking_rel_rms_pct_after': relative_rms_pct(desired[k], measured[k]),
    }


def recording_summary(recording: dict, kept) -> dict:
    """Return the summary's account of the recording: complete or not, and its gaps.

    ``recording``: per topic the ``info`` of :func:`aligned_steps` (without
    ``recorded``); ``kept``: per reviewed step, True if every topic holds it.
    """
    gaps = [dict(g, topic=topic) for topic, rec in recording.items() for g in rec['gap_list']]
    return {
        'recording_complete': not any(rec['filled'] for rec in recording.values()),
        'recording_missing_steps': {topic: rec['filled'] for topic, rec in recording.items()},
        'recording_gaps': sorted(gaps, key=lambda g: (g['first_step'], g['topic'])),
        'recording_longest_gap_steps': max((rec['longest_gap_steps']
                                            for rec in recording.values()), default=0),
        'recording_kept_pct': round(100.0 * float(np.mean(kept)), 3),
        'recording': {topic: {k: rec[k] for k in ('resent', 'filled', 'gaps',
                                                  'longest_gap_steps')}
                      for topic, rec in recording.items() if rec['resent'] or rec['filled']},
    }


#: Stages of :func:`rths_review.review.review_rths` reported to its ``progress``.
REVIEW_STAGES = 4


def bridge_realtime(status: dict, n_steps: int, fs_hz: float, limits=None) -> dict:
    """Real-time figures (:mod:`rths_review.realtime`) of the bridge's ticks of the run.

    ``status``: the bridge's entry of :func:`read_loop`.  Only the ticks of the run
    before any safety stop count (not those of its hold and ramp, which run without
    commands, nor those after the last step).
    """
    states = status.get('safety_state', [])
    in_run = [i for i, k in enumerate(status.get('step', [])) if k < n_steps]
    tripped = [i for i in in_run if states[i] != 0]
    if tripped:
        in_run = [i for i in in_run if i < tripped[0]]
    return realtime_figures([status['stamp_ns'][i] for i in in_run],
                            [status['missed'][i] for i in in_run], fs_hz, limits)


#: The real-time keys of a realtime run's summary.json.
REALTIME_KEYS = ('late_or_missed_pct', 'missed_ticks', 'clock_overruns', 'stalled_ticks',
                 'worst_period_ms', 'behind_s', 'realtime_ok', 'realtime_limits')


def run_account(bag, status: dict, planned_steps: int, recorded: int, recording: dict, kept,
                timing=None) -> dict:
    """Return the run's account in a review's summary.

    Deadline misses and safety faults of the bridge (``status``: its entry of
    :func:`read_loop`), the steps planned and recorded (``cut_short``), the recording's
    completeness (:func:`recording_summary`), the real-time figures of a realtime run
    (``timing``: :func:`bridge_realtime`'s, else None) and an external controller's
    counts (:func:`controller_counts`).
    """
    out = {
        'deadline_misses': int(status.get('misses', 0)),
        'deadline_miss_pct': 100.0 * status.get('misses', 0)
        / max(len(status.get('step', [])), 1),
        'safety_faults': status.get('faults', []),
        'planned_steps': int(planned_steps),
        'recorded_steps': recorded,
        'cut_short': recorded < planned_steps,
        **recording_summary(recording, kept),
    }
    if timing is not None:
        out.update({key: timing[key] for key in REALTIME_KEYS})
    counts = controller_counts(bag)
    if counts is not None:
        out['controller'] = counts
    return out
