"""Where do simulation and measurement disagree: in time, in frequency and in state.

* Time: rms of the residual ``r = y_meas - y_nom`` per window (1 s, or 1/16
  of the record), relative to the noise rms ``sigma``.
* Frequency: residual power per octave band relative to the noise power in
  that band (white noise floor ``sigma^2``).
* State (restoring-force-surface view): correlation of the residual with the
  states x, xd, sign(xd), xdd, the input and, where the record has a ``force``
  column (the specimen's measured damper force, eq. 45), that force.  For the
  specimen, also the restoring-force residual ``F_meas - (c_d xd + k_d x)``
  (zero for eq. 45-46 if the model is right) and the inertia residual
  ``F_meas + m_d (xdd + xdd_s)`` (eq. 45), each against the same states.
* Mean: the residual mean against its standard error (a constant sensor bias
  is invisible to whiteness tests).
"""

from itertools import pairwise

import numpy as np


def _corr(a, b):
    a = a - a.mean()
    b = b - b.mean()
    den = np.sqrt(np.sum(a * a) * np.sum(b * b))
    return float(np.sum(a * b) / den) if den > 0 else 0.0


def localize(ctx, data) -> dict:
    """Return the localisation dict (with human-readable 'summary' lines)."""
    r = ctx.y - ctx.y_nom
    fs, n = ctx.fs, ctx.n
    sigma = float(np.sqrt(ctx.sigma2))
    # time windows
    win = max(int(round(fs)), n // 16)
    nw = n // win
    rms = np.sqrt(np.mean(r[:nw * win].reshape(nw, win) ** 2, axis=1))
    order = np.argsort(rms)[::-1]
    windows = [{'t_start_s': float(i * win / fs), 't_end_s': float((i + 1) * win / fs),
                'residual_rms': float(rms[i]), 'ratio_to_noise': float(rms[i] / sigma)}
               for i in order[:3]]
    # frequency bands (octaves)
    spec = np.abs(np.fft.rfft(r - r.mean())) ** 2 / n
    f = np.fft.rfftfreq(n, 1.0 / fs)
    edges = [0.125]
    while edges[-1] * 2 < fs / 2:
        edges.append(edges[-1] * 2)
    edges.append(fs / 2)
    bands = []
    for lo, hi in pairwise(edges):
        sel = (f >= lo) & (f < hi)
        if sel.any():
            bands.append({'f_lo_hz': lo, 'f_hi_hz': hi,
                          'ratio_to_noise': float(np.mean(spec[sel]) / max(ctx.sigma2, 1e-300))})
    bands.sort(key=lambda b: -b['ratio_to_noise'])
    # state
    st = ctx.states
    feats = {'displacement': st['x'], 'velocity': st['v'], 'sign(velocity)': np.sign(st['v']),
             'acceleration': st['a'], 'input': ctx.u, 'displacement^3': st['x'] ** 3,
             'sign(displacement)': np.sign(st['x'])}
    if 'force' in data:
        feats['force'] = data['force']
    state = {'output_residual': {k: _corr(r, v) for k, v in feats.items()}}
    if ctx.scenario == 'specimen':
        m = ctx.model
        force = data['force']
        e_r = force - (m.c_d * st['v'] + m.k_d * st['x'])
        e_i = force + m.m_d * (st['a'] + ctx.u)
        state['restoring_force_residual'] = {k: _corr(e_r, v) for k, v in feats.items()}
        state['inertia_residual'] = {k: _corr(e_i, v) for k, v in feats.items()}
        state['restoring_force_residual_rms_N'] = float(np.std(e_r))
        state['inertia_residual_rms_N'] = float(np.std(e_i))
    mean = float(r.mean())
    se = sigma / np.sqrt(n) if sigma > 0 else 0.0
    summary = [
        'time: largest residual in ' + ', '.join(
            f"{w['t_start_s']:.1f}-{w['t_end_s']:.1f} s ({w['ratio_to_noise']:.1f}x noise)"
            for w in windows),
        'frequency: ' + ', '.join(
            f"{b['f_lo_hz']:g}-{b['f_hi_hz']:g} Hz ({b['ratio_to_noise']:.3g}x noise)"
            for b in bands[:3]),
    ]
    for key in ('output_residual', 'restoring_force_residual', 'inertia_residual'):
        if key in state:
            top = sorted(state[key].items(), key=lambda kv: -abs(kv[1]))[:3]
            summary.append(f'state ({key.replace("_", " ")}): ' + ', '.join(
                f'{k} r={v:+.2f}' for k, v in top))
    summary.append(f'mean: residual mean {mean:.3g} = {mean / se if se else 0:.1f} standard '
                   'errors of white noise')
    return {'time_windows': windows, 'frequency_bands': bands[:6], 'state': state,
            'residual_mean': mean, 'residual_mean_z': float(mean / se) if se else 0.0,
            'residual_rms_to_noise': float(np.sqrt(np.mean(r * r)) / sigma) if sigma > 0
            else 0.0,
            'summary': summary}


def nothing_found(where: dict) -> list:
    """Summary lines of a localisation when the workflow named no effect (``none``).

    The per-window and per-band ratios compare a residual with the noise floor; where
    nothing was found the residual lies within the floor as a whole, but a band's power
    can still be many times the floor's share of it (on a noise-free record the floor
    is the model resolution, not white noise), so ratios such as "1e+06x noise" there
    read as a finding.  Only the whole residual against the floor is stated.
    """
    return [f"nothing to localise: the residual's rms is {where['residual_rms_to_noise']:.2f}x "
            'the noise floor (on a noise-free record, the resolution of the model) and no '
            'effect of the library explains more of it than noise would; the per-window and '
            'per-band figures stay in result.json (localization)']
