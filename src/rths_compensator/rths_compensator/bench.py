"""The seed's numerical study of compensators (section 4.3.3), reproduced on a simulated plant.

1. Plant: the Table 1 3-pole model, ZOH at 1024 Hz (:func:`.plants.discrete_actuator`),
   with white measurement noise.
2. Identification (section 4.3.1.2): 10 training runs of BLWN (0-64 and 0-128 Hz, peaks
   2.54/5.08/12.7/25.4/38.1 mm) and 72 validation runs (10 s, 0-64 Hz, 2.54 or 5.08 mm);
   the 841-model ARX grid is fitted and the BIC winner histogram selects the model.
3. Design, on the IDENTIFIED model: 72 FIR compensators (LS/WLS/MM x n in {25, 50, 75,
   100, 200, 300} x fc in {32, 64, 96, 128} Hz) and the comparison compensators (inverse
   with the measured delay of each band, model-based feed-forward for both Table 1 models
   and alpha = 3, 5, 7, NPZ-Ignore, modified ZPETC, ZMETC).
4. Evaluation on the TRUE plant under four BLWN inputs (0-5, 0-10, 0-20, 0-30 Hz, peak
   5.08 mm): delay (eq. 42, from the H1 FRF estimate of the time series) and relative
   RMS error (eq. 43).
"""

import json
import os
import sys
import time

import numpy as np
from scipy import signal

from rths_common.files import atomic_open
from rths_common.progress import Progress
from rths_numerical.signals import blwn

from . import design as dsg
from ._blas import limit_blas_threads
from .filters import CausalFilter, MultiChannelFilter
from .identification import identify, selection_summary
from .indicators import bode, relative_rms_pct, time_delay_from_data, time_delay_ms
from .plants import discrete_actuator, unstable_zero_threshold_hz

BANDS_HZ = (5, 10, 20, 30)
FIR_TAPS = (25, 50, 75, 100, 200, 300)
FIR_FC_HZ = (32, 64, 96, 128)
SEED_TABLE2_DELAY_MS = {5: 14.9, 10: 16.7, 20: 20.8, 30: 21.1}

#: Zeros of the identified B* with modulus >= this go to B-* (not cancelled by the FIR
#: compensator's denominator B+*).  The BLWN runs excite 0-128 Hz only; the ARX model's
#: zeros above that band are unidentified, and the BIC model has a spurious pair at
#: |z| = 0.996 (154 Hz): cancelling it puts poles at 0.996 in G and a +60 dB resonance on
#: the real plant.  Lightly damped zeros are 'unacceptable' zeros in Tomizuka's ZPETC sense.
BENCH_ZERO_TOL = 0.98

#: Why the uncompensated delay differs from Table 2 (written into the JSON).
DELAY_NOTE = (
    'Table 2 reports the delay MEASURED on the laboratory actuator (0-5/10/20/30 Hz: '
    '14.9/16.7/20.8/21.1 ms). The bench simulates the Table 1 3-pole model (ZOH at 1024 Hz) '
    'instead; that model itself has a delay (eq. 42, averaged over the band) of '
    'table1_model_delay_ms = 14.93/15.69/19.05/19.89 ms (the 4-pole model: 14.60/15.78/'
    '19.21/20.13 ms), and the bench measures it from the noisy time series to within the H1 '
    'FRF estimation error. The 1.75 ms gap at 0-20 Hz (1.0 and 1.2 ms at 0-10 and 0-30 Hz) '
    'is the gap between the seed\'s fitted Table 1 model and its own hardware: a 3-pole fit '
    'cannot carry the extra phase lag the real servo-hydraulic loop shows between 10 and '
    '30 Hz. It is reported, not tuned away: matching Table 2 would need a different plant '
    'than Table 1.')


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def _blwn(duration_s, fs_hz, band_hz, peak, rng, taper_s=0.5):
    return blwn(duration_s, fs_hz, band_hz, peak, rng, taper_s)


def node_step_us(n_taps: int = 400, n_steps: int = 100000, seed: int = 0) -> dict:
    """Time ``CausalFilter.step`` and ``MultiChannelFilter.step`` (1 channel) per step [us]."""
    rng = np.random.default_rng(seed)
    taps = rng.standard_normal(n_taps) / n_taps
    x = rng.standard_normal(n_steps).tolist()
    filt = CausalFilter(taps)
    step = filt.step
    t0 = time.perf_counter()
    for v in x:
        step(v)
    single = (time.perf_counter() - t0) / n_steps * 1e6
    multi = MultiChannelFilter(taps, (1.0,), 1)
    xm = np.asarray(x)[:, None]
    t0 = time.perf_counter()
    for row in xm:
        multi.step(row)
    multi_us = (time.perf_counter() - t0) / n_steps * 1e6
    return {'causal_filter_us': single, 'multi_channel_us': multi_us}


def run_study(seed: int = 2024, noise_m: float = 2e-6, eval_s: float = 60.0,
              fs_hz: float = 1024.0, epsilon: float = dsg.DEFAULT_EPSILON,
              taps_list=FIR_TAPS, fc_list=FIR_FC_HZ, n_validation: int = 72,
              na_max: int = 29, nb_max: int = 29, train_s: float = 20.0,
              zero_tol: float = BENCH_ZERO_TOL, log=_log, val_s: float = 10.0,
              node_steps: int = 100000) -> dict:
    """Run the study; return the result dict (JSON layout of issue 3) plus ``_extra`` data.

    ``zero_tol`` is passed to :func:`.design.design_fir` (see :data:`BENCH_ZERO_TOL`).
    ``val_s`` is the length of each validation record [s], ``node_steps`` the number of
    filter steps timed (the defaults are the study's; tests shrink them).
    Every FIR entry carries ``highpass_gain_db`` (max ``20 log10 |T_com|`` from fc to
    Nyquist predicted on the identified model) and ``true_highpass_gain_db`` (the same
    for the true plant times the compensator).
    """
    limit_blas_threads(1)
    rng = np.random.default_rng(seed)
    b_true, a_true = discrete_actuator('3pole', fs_hz)

    def measure(u):
        return signal.lfilter(b_true, a_true, u) + noise_m * rng.standard_normal(u.size)

    # --- identification --------------------------------------------------------------
    log('[1/4] simulating identification runs (10 training, '
        f'{n_validation} validation records)')
    train = []
    for band in (64, 128):
        for peak_mm in (2.54, 5.08, 12.7, 25.4, 38.1):
            u = _blwn(train_s, fs_hz, band, peak_mm * 1e-3, rng)
            train.append((u, measure(u)))
    val = []
    for i in range(n_validation):
        u = _blwn(val_s, fs_hz, 64, (2.54 if i % 2 == 0 else 5.08) * 1e-3, rng)
        val.append((u, measure(u)))
    log(f'[2/4] ARX grid na, nb = 1..{na_max}, 1..{nb_max} ({na_max * nb_max} models), '
        f'selection over {n_validation} validation records')

    t0 = time.perf_counter()
    with Progress(na_max * nb_max, 'ARX grid', 'models') as bar:
        model, info, grid = identify(train, val, fs_hz, na_max, nb_max, 0, 'bic',
                                     progress=bar.report)
        bar.update(bar.total)                         # (the grid reports every 100 models)
    arx_s = time.perf_counter() - t0
    zeros = np.roots(model.b) if model.nb > 1 else np.array([])
    log(f'      selected (BIC) na={model.na} nb={model.nb} d={model.d} in {arx_s:.1f} s; '
        f'zero moduli {np.round(np.abs(zeros), 3).tolist()}')

    # --- evaluation inputs and uncompensated plant ----------------------------------
    inputs = {band: _blwn(eval_s, fs_hz, band, 5.08e-3, rng, taper_s=1.0) for band in BANDS_HZ}

    def evaluate(taps, den):
        out = {}
        for band, r in inputs.items():
            u = signal.lfilter(taps, den, r)
            y = measure(u)
            out[str(band)] = {'delay_ms': time_delay_from_data(r, y, fs_hz, band),
                              'rel_rms_pct': relative_rms_pct(r, y)}
        return out

    uncompensated = evaluate(np.array([1.0]), np.array([1.0]))
    log('      uncompensated delay ' + ', '.join(
        f'0-{b} Hz: {uncompensated[str(b)]["delay_ms"]:.2f} ms' for b in BANDS_HZ))

    # --- designs ----------------------------------------------------------------------
    log(f'[3/4] designing {3 * len(taps_list) * len(fc_list)} FIR compensators '
        f'(epsilon = {epsilon})')
    compensators, designs = [], {}
    fir_total = fir_cpu = 0.0
    bar = Progress(len(dsg.FIR_SCHEMES) * len(taps_list) * len(fc_list), 'FIR designs')
    for scheme in dsg.FIR_SCHEMES:
        for n in taps_list:
            for fc in fc_list:
                name = f'fir-{scheme}-n{n}-fc{fc}'
                t0, c0 = time.perf_counter(), time.process_time()
                try:
                    d = dsg.design_fir(model, n, fc, scheme, epsilon, zero_tol=zero_tol)
                    err = None
                except ValueError as exc:
                    d, err = None, str(exc)
                dt = time.perf_counter() - t0
                fir_total += dt
                fir_cpu += time.process_time() - c0
                entry = {'name': name, 'scheme': scheme, 'taps': n, 'fc_hz': fc,
                         'design_s': dt, 'bands': evaluate(d.taps, d.denominator) if d else None}
                if d is not None:
                    entry['highpass_gain_db'] = dsg.predict(model, d, fc)['highpass_gain_db']
                    entry['true_highpass_gain_db'] = dsg.predict(
                        (b_true, a_true), d, fc, fs_hz)['highpass_gain_db']
                if err:
                    entry['error'] = err
                    with bar.hidden():
                        log(f'      {name}: FAILED {err}')
                compensators.append(entry)
                designs[name] = d
                bar.advance()
    bar.close()
    log(f'      {len(compensators)} FIR designs in {fir_total:.1f} s; comparison compensators')
    others = []
    for band in BANDS_HZ:
        others.append((f'inverse-tau{band}hz', 'inverse',
                       lambda band=band: dsg.design_inverse(
                           fs_hz, uncompensated[str(band)]['delay_ms'])))
    for kind in ('3pole', '4pole'):
        for alpha in (3, 5, 7):
            others.append((f'mff-{kind}-alpha{alpha}', 'mff',
                           lambda kind=kind, alpha=alpha: dsg.design_mff(kind, alpha, fs_hz)))
    others += [('npz-ignore', 'npz', lambda: dsg.design_npz(model)),
               ('zpetc', 'zpetc', lambda: dsg.design_zpetc(model)),
               ('zmetc', 'zmetc', lambda: dsg.design_zmetc(model))]
    for name, scheme, make in others:
        t0 = time.perf_counter()
        try:
            d, err = make(), None
        except ValueError as exc:
            d, err = None, str(exc)
        dt = time.perf_counter() - t0
        entry = {'name': name, 'scheme': scheme, 'taps': None, 'fc_hz': None, 'design_s': dt,
                 'bands': evaluate(d.taps, d.denominator) if d else None}
        if err:
            entry['error'] = err
            log(f'      {name}: FAILED {err}')
        compensators.append(entry)
        designs[name] = d

    log(f'[4/4] timing the node filter step (400 taps, {node_steps} steps)')
    step = node_step_us(400, node_steps)
    fir_ok = [c for c in compensators if 'highpass_gain_db' in c]
    result = {
        'uncompensated': {'bands': uncompensated},
        'table1_model_delay_ms': {str(b): time_delay_ms(b_true, a_true, fs_hz, b)
                                  for b in BANDS_HZ},
        'delay_note': DELAY_NOTE,
        'identified_model': {'na': model.na, 'nb': model.nb, 'd': model.d,
                             'zero_moduli': np.round(np.abs(zeros), 4).tolist(),
                             'zero_tol': zero_tol},
        'fir_highpass_gain_db': {
            'median_predicted': float(np.median([c['highpass_gain_db'] for c in fir_ok])),
            'max_predicted': float(np.max([c['highpass_gain_db'] for c in fir_ok])),
            'median_true_plant': float(np.median([c['true_highpass_gain_db']
                                                  for c in fir_ok])),
            'max_true_plant': float(np.max([c['true_highpass_gain_db'] for c in fir_ok]))}
        if fir_ok else None,
        'compensators': compensators,
        'fir_design_total_s': fir_total,
        'fir_design_cpu_s': fir_cpu,
        'arx_selection_s': arx_s,
        'unstable_zero_fs_hz': {'3pole': unstable_zero_threshold_hz('3pole'),
                                '4pole': unstable_zero_threshold_hz('4pole')},
        'node_step_us_400taps': max(step.values()),
    }
    result['_extra'] = {'model': model, 'selection': info, 'grid': grid, 'designs': designs,
                        'step': step, 'settings': {
                            'seed': seed, 'noise_m': noise_m, 'eval_s': eval_s,
                            'epsilon': epsilon, 'fs_hz': fs_hz}}
    return result


def targets(result: dict) -> list:
    """Check the issue-3 targets; return a list of (name, measured, limit, ok) rows."""
    rows = []
    unc = result['uncompensated']['bands']
    for band in BANDS_HZ:
        got = unc[str(band)]['delay_ms']
        ref = SEED_TABLE2_DELAY_MS[band]
        model_ms = result.get('table1_model_delay_ms', {}).get(str(band))
        extra = f' (Table 1 model: {model_ms:.2f} ms)' if model_ms is not None else ''
        rows.append((f'uncompensated delay 0-{band} Hz vs Table 2 {ref} ms', f'{got:.2f} ms'
                     + extra, '|diff| <= 1.5 ms', abs(got - ref) <= 1.5))
    by_name = {c['name']: c for c in result['compensators']}
    ls = by_name.get('fir-ls-n100-fc64')
    if ls and ls['bands']:
        for band in BANDS_HZ:
            got = ls['bands'][str(band)]['delay_ms']
            rows.append((f'FIR LS n=100 fc=64 delay 0-{band} Hz', f'{got:.3f} ms',
                         '|delay| <= 0.1 ms', abs(got) <= 0.1))
        for band, lim in ((20, 5.0), (30, 10.0)):
            got = ls['bands'][str(band)]['rel_rms_pct']
            rows.append((f'FIR LS n=100 fc=64 rel. RMS 0-{band} Hz', f'{got:.2f} %',
                         f'<= {lim} %', got <= lim))
            best = min((c for c in result['compensators'] if c['bands']),
                       key=lambda c: c['bands'][str(band)]['rel_rms_pct'])
            others = [c for c in result['compensators'] if c['bands'] and c['scheme'] not in
                      dsg.FIR_SCHEMES]
            best_other = min(others, key=lambda c: c['bands'][str(band)]['rel_rms_pct'])
            rows.append((f'FIR LS n=100 fc=64 lowest rel. RMS 0-{band} Hz of all',
                         f'best: {best["name"]} {best["bands"][str(band)]["rel_rms_pct"]:.2f} %'
                         f'; best non-FIR: {best_other["name"]} '
                         f'{best_other["bands"][str(band)]["rel_rms_pct"]:.2f} %',
                         'FIR LS n100 fc64 lowest',
                         best['name'] == 'fir-ls-n100-fc64'))
            other_rms = best_other['bands'][str(band)]['rel_rms_pct']
            rows.append((f'FIR LS n=100 fc=64 lower rel. RMS than every non-FIR 0-{band} Hz',
                         f'{got:.2f} %', f'< {other_rms:.2f} %', got < other_rms))
    cpu = result.get('fir_design_cpu_s')
    rows.append(('72 FIR designs total', f'{result["fir_design_total_s"]:.1f} s'
                 + (f' (CPU {cpu:.1f} s)' if cpu is not None else ''), '<= 60 s',
                 result['fir_design_total_s'] <= 60))
    rows.append(('ARX grid + selection', f'{result["arx_selection_s"]:.1f} s', '<= 60 s',
                 result['arx_selection_s'] <= 60))
    rows.append(('node step, 400 taps', f'{result["node_step_us_400taps"]:.2f} us', '<= 20 us',
                 result['node_step_us_400taps'] <= 20))
    for kind, ref in (('3pole', 41.0), ('4pole', 42.0)):
        got = result['unstable_zero_fs_hz'][kind]
        rows.append((f'Appendix I threshold {kind} vs seed ~{ref:.0f} Hz', f'{got:.2f} Hz',
                     '|diff| <= 1 Hz', abs(got - ref) <= 1.0))
    return rows


def write_json(path, result: dict) -> str:
    """Atomically write the public part of ``result`` (no ``_extra``) as JSON."""
    public = {k: v for k, v in result.items() if not k.startswith('_')}
    with atomic_open(path) as handle:
        json.dump(public, handle, indent=1)
    return path


def make_plots(result: dict, directory: str) -> list:
    """Write PNG figures mirroring the seed's Figures 5-10 into ``directory``."""
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib
    matplotlib.use('Agg')
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib.pyplot as plt

    os.makedirs(directory, exist_ok=True)
    extra = result['_extra']
    model, designs = extra['model'], extra['designs']
    fs = model.fs_hz
    files = []

    # Figure 5: BIC winner histogram
    hist = extra['grid']['histogram']['bic']
    items = sorted(hist.items(), key=lambda kv: -kv[1])[:15]
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.bar([f'{o[0]},{o[1]}' for o, _ in items], [c for _, c in items])
    ax.set_xlabel('ARX model (na, nb)')
    ax.set_ylabel('times selected (BIC)')
    ax.set_title('Figure 5: BIC winners over the validation records')
    ax.tick_params(axis='x', rotation=60)
    fig.tight_layout()
    files.append(os.path.join(directory, 'fig5_bic_histogram.png'))
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)

    # Figure 6: Bode of the plant and compensated plant (n = 100, fc = 32 Hz)
    freqs = np.logspace(-1, np.log10(fs / 2), 600)
    fig, axes = plt.subplots(2, 2, figsize=(11, 6), sharex=True)
    f, mag, ph, _ = bode(model.num, model.a, fs, freqs)
    axes[0, 0].semilogx(f, mag)
    axes[1, 0].semilogx(f, ph)
    axes[0, 0].set_title('(a) identified plant, no compensation')
    for scheme in dsg.FIR_SCHEMES:
        d = designs.get(f'fir-{scheme}-n100-fc32')
        if d is None:
            continue
        num, den = dsg.compensated(model, d)
        f, mag, ph, _ = bode(num, den, fs, freqs)
        axes[0, 1].semilogx(f, mag, label=scheme.upper())
        axes[1, 1].semilogx(f, ph, label=scheme.upper())
    axes[0, 1].set_title('(b) with FIR compensators n = 100, fc = 32 Hz')
    if axes[0, 1].get_legend_handles_labels()[0]:
        axes[0, 1].legend()
    for ax in axes[0]:
        ax.set_ylabel('magnitude [dB]')
        ax.grid(True, which='both', alpha=0.3)
    for ax in axes[1]:
        ax.set_ylabel('phase [deg]')
        ax.set_xlabel('frequency [Hz]')
        ax.grid(True, which='both', alpha=0.3)
    fig.tight_layout()
    files.append(os.path.join(directory, 'fig6_bode.png'))
    fig.savefig(files[-1], dpi=110)
    plt.close(fig)

    # Figures 7 and 8: delay and RMS surfaces at 0-20 Hz
    fir = [c for c in result['compensators'] if c['scheme'] in dsg.FIR_SCHEMES and c['bands']]
    taps = sorted({c['taps'] for c in fir})
    fcs = sorted({c['fc_hz'] for c in fir})
    for fig_no, key, label in ((7, 'delay_ms', 'time delay [ms]'),
                               (8, 'rel_rms_pct', 'relative RMS error [%]')):
        fig = plt.figure(figsize=(14, 4.5))
        for i, scheme in enumerate(dsg.FIR_SCHEMES):
            z = np.full((len(fcs), len(taps)), np.nan)
            for c in fir:
                if c['scheme'] == scheme:
                    z[fcs.index(c['fc_hz']), taps.index(c['taps'])] = c['bands']['20'][key]
            ax = fig.add_subplot(1, 3, i + 1, projection='3d')
            xx, yy = np.meshgrid(taps, fcs)
            ax.plot_surface(xx, yy, z, cmap='viridis', alpha=0.8)
            ax.scatter(xx, yy, z, color='k', s=8)
            ax.set_xlabel('n')
            ax.set_ylabel('fc [Hz]')
            ax.set_zlabel(label)
            ax.set_title(f'{scheme.upper()} (BLWN 0-20 Hz)')
        fig.tight_layout()
        name = 'fig7_delay_surfaces.png' if fig_no == 7 else 'fig8_rms_surfaces.png'
        files.append(os.path.join(directory, name))
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)

    # Figures 9 and 10: comparison bars
    by_name = {c['name']: c for c in result['compensators']}
    series = [('uncompensated', result['uncompensated']['bands'])]
    for name, label in (('fir-ls-n100-fc64', 'FIR LS n=100 fc=64'),
                        ('mff-3pole-alpha7', 'MFF 3-pole a=7'), ('npz-ignore', 'NPZ-Ignore'),
                        ('zpetc', 'ZPETC'), ('zmetc', 'ZMETC')):
        if by_name.get(name) and by_name[name]['bands']:
            series.append((label, by_name[name]['bands']))
    inv = {}
    for band in BANDS_HZ:
        c = by_name.get(f'inverse-tau{band}hz')
        if c and c['bands']:
            inv[str(band)] = c['bands'][str(band)]
    if len(inv) == len(BANDS_HZ):
        series.append(('inverse (matched tau)', inv))
    for fig_no, key, label in ((9, 'delay_ms', 'time delay [ms]'),
                               (10, 'rel_rms_pct', 'relative RMS error [%]')):
        fig, ax = plt.subplots(figsize=(10, 4.5))
        width = 0.8 / len(series)
        x = np.arange(len(BANDS_HZ))
        for i, (label_s, bands) in enumerate(series):
            ax.bar(x + i * width, [bands[str(b)][key] for b in BANDS_HZ], width, label=label_s)
        ax.set_xticks(x + 0.4 - width / 2)
        ax.set_xticklabels([f'0-{b} Hz' for b in BANDS_HZ])
        ax.set_ylabel(label)
        if key == 'delay_ms':
            ax.axhline(1.0, ls='--', color='k', lw=0.8)
            ax.axhline(-1.0, ls='--', color='k', lw=0.8)
        ax.legend(fontsize=8)
        ax.grid(True, axis='y', alpha=0.3)
        fig.tight_layout()
        name = 'fig9_delay_comparison.png' if fig_no == 9 else 'fig10_rms_comparison.png'
        files.append(os.path.join(directory, name))
        fig.savefig(files[-1], dpi=110)
        plt.close(fig)
    return files


__all__ = ['run_study', 'targets', 'write_json', 'make_plots', 'node_step_us',
           'selection_summary']
