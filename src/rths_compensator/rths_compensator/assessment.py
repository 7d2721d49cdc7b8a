"""What a designed compensator will do, and whether the actuator's limits allow it.

Predictions (:func:`predict_all`), every one printed and written by ``rths design``:

* the compensator ``G`` alone: its gain peak (and where), its gain at Nyquist (the
  high-frequency gain), the peak of the command it produces for a unit step, and for the
  reference desired displacement below the ratio of command peak to desired peak;
* the compensated loop ``T_com = P G`` on the MODEL it was designed on: mean delay over the
  band (eq. 42), largest gain error in it, and the loop's largest gain above the band;
* the compensated loop on the RECORD (its held-out part): the record's own impulse
  response, estimated without a model (:func:`.estimation.impulse_response`), replaces
  the model, and the reference's command passes through it; a model that is wrong where
  the record is right shows here.  (On a 2000 Hz record with 0.5 % noise it predicted
  0.19 % where the true actuator tracked 0.17 %; the Welch FRF's leakage made it 1.1 %.)

Limits (:class:`DesignLimits`, from the bridge's parameters: ``stroke_m``,
``velocity_m_s``, ``acceleration_m_s2`` -- the supervisor's limits, the last one standing
for the force the actuator may put into the table).  The reference desired displacement
is the identification record's measured displacement band-limited (ideal zero-phase
low-pass) to the design band: a motion the actuator has already made, at the lab's own
amplitude, in the band the compensator is meant for.  The command ``G r`` must stay inside every
limit; a compensator that would drive that motion into the stroke, velocity or
acceleration limit is refused (:func:`check_limits`), with the figure and the fix.
Without a record the reference is band-limited white noise over the band with a peak of
``REFERENCE_PEAK_FRACTION`` of the stroke (the seed's identification peak, 2.54 mm of
+-254 mm); its amplitude is assumed, so ``rths design`` then warns instead of refusing.
"""

import dataclasses
from pathlib import Path

import numpy as np
from scipy import signal

from rths_common.runinfo import load_params
from rths_numerical.signals import blwn

from .design import compensated
from .estimation import design_score_target, impulse_response
from .indicators import time_delay_ms

#: Peak of the reference desired displacement when no record is at hand, as a fraction of
#: the stroke.
REFERENCE_PEAK_FRACTION = 0.01
#: Seeds of the noise-like targets whose commands are checked too (the worst counts): a
#: target that starts from rest puts a little motion above the band, which a compensator
#: with a large gain there amplifies; how much depends on the draw (3x between seeds on the
#: 4096 Hz, 20 ms bench plant).
NOISE_SEEDS = (1, 2, 3, 4, 5)
#: Gain weights (design._with_gain_rows) tried in turn when the default least-squares
#: design's command exceeds a limit: each 10x halves the command's acceleration for a
#: noise-like target on the 4096 Hz, 20 ms bench plant (403 -> 208 -> 110 m/s^2) and costs
#: little tracking (0-10 Hz noise 0.284 -> 0.304 -> 0.337 %).
ADAPT_GAIN_WEIGHTS = (1e-5, 1e-4, 1e-3)


@dataclasses.dataclass
class DesignLimits:
    """The actuator's command limits [m, m/s, m/s^2] and where they were read."""

    stroke_m: float
    velocity_m_s: float
    acceleration_m_s2: float
    source: str = ''

    @classmethod
    def from_bridge_params(cls, path) -> 'DesignLimits':
        """Read ``stroke_m``, ``velocity_m_s``, ``acceleration_m_s2`` of a bridge params file."""
        params = load_params(path, 'bridge')
        values = {}
        for key in ('stroke_m', 'velocity_m_s', 'acceleration_m_s2'):
            if key not in params:
                raise ValueError(f'{path}: bridge parameter {key} missing; the design limits '
                                 'are derived from stroke_m, velocity_m_s, acceleration_m_s2')
            value = float(params[key])
            if not value > 0:
                raise ValueError(f'{path}: bridge parameter {key} = {value} must be > 0')
            values[key] = value
        return cls(**values, source=str(Path(path)))


def reference_signal(fs_hz: float, band_hz: float, measured=None, limits=None,
                     duration_s: float = 20.0, seed: int = 0):
    """Return the reference desired displacement (module docstring) and a text naming it."""
    cutoff = min(band_hz, 0.45 * fs_hz)
    if measured is not None:
        y = np.asarray(measured, dtype=float)
        spectrum = np.fft.rfft(y - np.mean(y))
        spectrum[np.fft.rfftfreq(y.size, 1.0 / fs_hz) > cutoff] = 0.0
        r = np.fft.irfft(spectrum, y.size)
        m = min(int(round(fs_hz)), r.size // 4)          # start and end at rest: 1 s tapers
        ramp = 0.5 * (1 - np.cos(np.linspace(0.0, np.pi, m)))
        r[:m] *= ramp
        r[r.size - m:] *= ramp[::-1]
        return r, f'the record\'s measured displacement in 0-{cutoff:.3g} Hz'

    peak = REFERENCE_PEAK_FRACTION * (limits.stroke_m if limits else 0.254)
    return (blwn(duration_s, fs_hz, cutoff, peak, seed, 0.5),
            f'band-limited white noise 0-{cutoff:.3g} Hz, peak {peak * 1e3:.3g} mm')


def _response(taps, denominator, x):
    return signal.lfilter(taps, denominator, x)


def noise_targets(fs_hz: float, band_hz: float, peak: float) -> list:
    """Return the noise-like desired motions of the limit check: noise over the band.

    20 s of white noise band-limited to ``band_hz`` faded in and out over 0.5 s (as an
    RTHS target starts from rest) with a peak of ``peak``, one per :data:`NOISE_SEEDS`.
    """
    cutoff = min(band_hz, 0.45 * fs_hz)
    return [peak * design_score_target(fs_hz, cutoff, seed) for seed in NOISE_SEEDS]


def command_figures(comp, x) -> dict:
    """Peak [m], velocity [m/s] and acceleration [m/s^2] of the command for the target ``x``."""
    command = _response(comp.taps, comp.denominator, x)
    fs = comp.fs_hz
    return {'peak_m': float(np.max(np.abs(command))),
            'velocity_m_s': float(np.max(np.abs(np.diff(command)))) * fs,
            'acceleration_m_s2': float(np.max(np.abs(np.diff(command, 2)))) * fs ** 2}


def noise_figures(comp, band_hz: float, peak: float) -> dict:
    """Return the worst command figures over :func:`noise_targets` (``noise_command_*``)."""
    worst = {}
    for x in noise_targets(comp.fs_hz, band_hz, peak):
        for key, value in command_figures(comp, x).items():
            worst[key] = max(worst.get(key, 0.0), value)
    return {f'noise_command_{key}': value for key, value in worst.items()}


def compensator_figures(comp, band_hz: float, reference) -> dict:
    """Predictions of the compensator alone (module docstring)."""
    fs = comp.fs_hz
    f = np.linspace(0.0, fs / 2, 4097)
    _, h = signal.freqz(comp.taps, comp.denominator, worN=f, fs=fs)
    mag = np.abs(h)
    k = int(np.argmax(mag))
    n_step = int(max(comp.taps.size * 2, round(fs)))
    step = _response(comp.taps, comp.denominator, np.ones(n_step))
    command = _response(comp.taps, comp.denominator, reference)
    dt = 1.0 / fs
    return {
        'gain_peak_db': float(20 * np.log10(mag[k])),
        'gain_peak_hz': float(f[k]),
        'hf_gain_db': float(20 * np.log10(max(mag[-1], 1e-300))),
        'step_command_peak': float(np.max(np.abs(step))),
        'reference_command_ratio': float(np.max(np.abs(command)) / np.max(np.abs(reference))),
        'reference_command_peak_m': float(np.max(np.abs(command))),
        'reference_command_velocity_m_s': float(np.max(np.abs(np.diff(command))) / dt),
        'reference_command_acceleration_m_s2': float(np.max(np.abs(np.diff(command, 2)))
                                                     / dt ** 2),
    }


def loop_figures_model(plant, comp, band_hz: float, n_points: int = 512) -> dict:
    """Predictions of ``T_com = P G`` on the plant model (delay, gain error, gain above band)."""
    num, den = compensated(plant, comp)
    fs = comp.fs_hz
    delay = time_delay_ms(num, den, fs, band_hz, n_points)
    f_in = np.linspace(band_hz / n_points, band_hz, n_points)
    f_out = np.linspace(band_hz, fs / 2, 2 * n_points)
    _, h_in = signal.freqz(num, den, worN=f_in, fs=fs)
    _, h_out = signal.freqz(num, den, worN=f_out, fs=fs)
    return {'delay_ms': float(delay),
            'gain_error_db': float(np.max(np.abs(20 * np.log10(np.abs(h_in))))),
            'loop_gain_above_band_db': float(np.max(20 * np.log10(np.abs(h_out))))}


def loop_figures_record(comp, record, reference, memory_s: float = 0.5) -> dict:
    """Predicted tracking [%] of the compensated loop on the record's held-out part.

    ``record`` is ``(command, measured, split)``.  The plant is the record's own impulse
    response (:func:`.estimation.impulse_response`, ``memory_s`` long, fitted on
    ``[split:]`` only), not the parametric model: the reference's command passes through it
    and the error is compared with the reference (eq. 43).
    """
    u, y, split = record
    n_lags = int(min(round(memory_s * comp.fs_hz), max(8, (len(u) - split) // 10)))
    h = impulse_response(u, y, n_lags, split)
    command = _response(comp.taps, comp.denominator, reference)
    y_pred = signal.lfilter(h, [1.0], command)
    return {'record_tracking_pct': float(100 * np.linalg.norm(y_pred - reference)
                                         / np.linalg.norm(reference)),
            'record_memory_s': n_lags / comp.fs_hz}


def predict_all(plant, comp, band_hz: float, reference, record=None) -> dict:
    """Every prediction of the module docstring in one flat dict.

    ``record`` is the identification record ``(command, measured, split)``, or None.
    """
    out = compensator_figures(comp, band_hz, reference)
    out.update(loop_figures_model(plant, comp, band_hz))
    if record is not None:
        out.update(loop_figures_record(comp, record, reference))
    return out


#: The limits a command is checked against: (figure of the command, DesignLimits field, unit).
LIMIT_ROWS = (('peak_m', 'stroke_m', 'm'), ('velocity_m_s', 'velocity_m_s', 'm/s'),
              ('acceleration_m_s2', 'acceleration_m_s2', 'm/s^2'))


def exceeded_limits(figures: dict, limits: DesignLimits) -> list:
    """Return the limits a command's figures exceed, as ``{'limit', 'value', 'bound'}`` dicts.

    ``figures`` holds the command's ``peak_m``, ``velocity_m_s`` and ``acceleration_m_s2``;
    ``limit`` is the bridge parameter's name (``stroke_m``, ``velocity_m_s``,
    ``acceleration_m_s2``).  A non-finite figure exceeds its limit.  Empty: within every limit.
    """
    out = []
    for key, name, _ in LIMIT_ROWS:
        value, bound = float(figures[key]), float(getattr(limits, name))
        if not value <= bound:
            out.append({'limit': name, 'value': value, 'bound': bound})
    return out


def check_limits(pred: dict, limits: DesignLimits, reference_text: str) -> list:
    """Return the violated limits as lines (empty: within every limit).

    Both commands are checked: the reference's (``reference_command_*``) and the worst
    noise-like target's (``noise_command_*``, :func:`noise_figures`), when predicted.
    """
    units = {name: unit for _, name, unit in LIMIT_ROWS}
    out = []
    targets = [('reference', f'the reference ({reference_text})')]
    if 'noise_command_peak_m' in pred:
        targets.append(('noise', f'band-limited noise over the band at the record\'s peak '
                                 f'({1e3 * pred["noise_peak_m"]:.3g} mm, 0.5 s fades, worst '
                                 f'of {len(NOISE_SEEDS)} draws)'))
    for prefix, text in targets:
        figures = {key: pred[f'{prefix}_command_{key}'] for key, _, _ in LIMIT_ROWS}
        out += [f'the command for {text} reaches {e["value"]:.4g} {units[e["limit"]]}, above '
                f'{e["limit"]} = {e["bound"]:g} {units[e["limit"]]} '
                f'({limits.source or "limits"})' for e in exceeded_limits(figures, limits)]
    return out


def assess(plant, comp, band_hz: float, record=None, limits: DesignLimits = None):
    """Predict a design and check it against the limits: ``(pred, violations, reference_text)``.

    ``record`` is the identification record ``(command, measured, split)`` or None; the
    predictions on the record use its held-out part ``[split:]``.
    """
    measured = record[1] if record is not None else None
    reference, text = reference_signal(comp.fs_hz, band_hz, measured, limits)
    pred = predict_all(plant, comp, band_hz, reference, record)
    if record is not None:      # the largest motion the lab commanded or measured in it
        peak = max(float(np.max(np.abs(np.asarray(x) - np.mean(x)))) for x in record[:2])
    else:
        peak = REFERENCE_PEAK_FRACTION * (limits.stroke_m if limits else 0.254)
    pred['noise_peak_m'] = peak
    pred['noise_draws'] = len(NOISE_SEEDS)
    pred.update(noise_figures(comp, band_hz, peak))
    violations = check_limits(pred, limits, text) if limits is not None else []
    return pred, violations, text


def design_within_limits(plant, design_fn, band_of, record=None,
                         limits: DesignLimits = None, adapt: bool = True):
    """Design, assess, and raise the gain weight while a command exceeds a limit.

    ``design_fn(gain_weight)`` returns a design (``gain_weight`` None: its default);
    ``band_of(comp)`` the band of its predictions.  With ``adapt`` (a least-squares scheme
    whose gain weight the user did not choose) and limits given, a design whose command for
    the reference or a noise-like target exceeds a limit is redesigned with the next of
    :data:`ADAPT_GAIN_WEIGHTS` (more weight on the compensator's own gain above the band)
    until it is within every limit.
    Returns ``(comp, band, pred, violations, text, note)``; ``note`` says what was adapted
    ('' if nothing), ``violations`` those of the last design tried.
    """
    comp = design_fn(None)
    band = band_of(comp)
    pred, violations, text = assess(plant, comp, band, record, limits)
    note = ''
    if not adapt or limits is None or not violations:
        return comp, band, pred, violations, text, note
    first = violations[0]
    start = float(comp.info.get('gain_weight') or 0.0)
    for weight in (w for w in ADAPT_GAIN_WEIGHTS if w > start):
        comp = design_fn(weight)
        band = band_of(comp)
        pred, violations, text = assess(plant, comp, band, record, limits)
        note = f'gain weight raised from {start:g} to {weight:g} (at {start:g}, {first})'
        if not violations:
            break
    return comp, band, pred, violations, text, note
