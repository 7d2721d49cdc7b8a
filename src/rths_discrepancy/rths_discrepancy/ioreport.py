"""The io scenario's report: result.json, a one-page report.md and its evidence plots.

Read in a minute: the baseline beside the ARX reference, every candidate block with
its score, the chosen effect, the held-out gap before and after, and per output one
plot of the held-out response (measured, linear, updated) with its residuals.
"""

import json
import os

import numpy as np

from rths_discrepancy.report import _atomic_write


def write(out_dir, result, per, plots=True):
    """Write result.json, report.md and (``plots``) one PNG per output to ``out_dir``."""
    os.makedirs(out_dir, exist_ok=True)
    files = {}
    if plots:
        for name, p in per.items():
            files[name] = _plot(out_dir, name, p)
    _atomic_write(os.path.join(out_dir, 'result.json'), json.dumps(result, indent=2))
    _atomic_write(os.path.join(out_dir, 'report.md'), markdown(result, files))


def _plot(out_dir, name, p):
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib
    matplotlib.use('Agg')
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib.pyplot as plt
    d = p['_plot']
    y, b, a = d['t_test'], d['before'], d['after']
    k = np.arange(y.size)
    fig, ax = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    ax[0].plot(k, y, lw=0.5, color='0.4', label='measured (held out)')
    ax[0].plot(k, b, lw=0.5, color='C0', label='linear baseline')
    ax[0].plot(k, a, lw=0.5, color='C3', label='updated model')
    ax[0].set_ylabel(name)
    ax[0].legend(fontsize=8, loc='upper right')
    ax[1].plot(k, y - b, lw=0.5, color='C0', label='residual before')
    ax[1].plot(k, y - a, lw=0.5, color='C3', label='residual after')
    ax[1].set_xlabel('held-out sample')
    ax[1].legend(fontsize=8, loc='upper right')
    fig.tight_layout()
    fname = f'heldout_{"".join(c if c.isalnum() else "_" for c in name)}.png'
    fig.savefig(os.path.join(out_dir, fname), dpi=90)
    plt.close(fig)
    return fname


#: A free-run NRMSE above this is a simulation that diverged, not an error size.
DIVERGED_NRMSE = 100.0


def nrmse_cell(x):
    """Table cell of a training NRMSE: '-' when not fitted, 'diverged' when unstable."""
    if x is None:
        return '-'
    if not x <= DIVERGED_NRMSE:
        return 'diverged (free run unstable)'
    return f'{x:.4f}'


def _measure_lines(name, p):
    m = p.get('error_measure') or {}
    out = []
    if 'horizon_samples' in m:
        out.append(f"Output `{name}`: {m['kind']}, every {m['horizon_samples']} samples "
                   f"({m['horizon_periods']:.1f} periods of the {m['dominant_mode_hz']:.4g} Hz "
                   f"mode); {m['why']}. Baseline here: {m.get('baseline_model', 'baseline')}; "
                   f"free-run NRMSE {p['free_run_nrmse_baseline']:.4f} -> "
                   f"{p['free_run_nrmse_after']:.4f}.")
    c = p.get('heldout_confirmation')
    if c and not c['confirmed']:
        out.append(f"Output `{name}`: `{c['block']}` was chosen on the training records "
                   f"(error -{100 * c['training_relative_gain']:.0f} %) but the held-out part "
                   f"does not confirm it (-{100 * c['heldout_relative_gain']:.0f} %): not named.")
    if p.get('limit_only_in_heldout_part'):
        out.append(f"Output `{name}`: the whole record's output plateaus where the training "
                   'part does not (a limit the training records cannot show): `unexplained`, '
                   'not a name read into a few clipped samples.')
    elif 'unexplained' in p.get('effects', []):
        out.append(f"Output `{name}`: the baseline misses the held-out part far more than the "
                   'training records and no block explains it: `unexplained` (the training '
                   'part does not show what the later part holds).')
    return out + ([''] if out else [])


def markdown(result, files):
    """Return report.md of an io run."""
    lines = ['# Discrepancy report (input-output)', '',
             f"Input `{result['input']}` -> output(s) "
             + ', '.join(f'`{o}`' for o in result['outputs'])
             + f" at {result['sample_rate_hz']:g} Hz; trained on "
             + ', '.join(result['training_records']) + '; held out: '
             + ', '.join(result['heldout_records']) + '.', '',
             f"**Effect: `{result['effect']}`**", '',
             '| output | linear baseline | ARX reference | after | named |',
             '|---|---|---|---|---|']
    for name, p in result['per_output'].items():
        lines.append(f"| {name} | {p['nrmse_baseline']:.4f} | {p['nrmse_reference']:.4f} | "
                     f"{p['nrmse_after']:.4f} | {'+'.join(p['effects']) or 'none'} |")
    lines += ['', 'Held-out NRMSE (rms error / std of the measured output) in the measure '
              'stated per output: free-run simulation, or, where no model simulates the '
              'training records free-run, simulation re-initialised from the measured '
              'output every few periods. The baseline is the linear model of '
              'rths_discrepancy.linear (orders from the data, output-error refined); the '
              'reference is the plain ARX of the project\'s identification at the '
              'record\'s rate.', '']
    for name, p in result['per_output'].items():
        lines += _measure_lines(name, p)
    for name, p in result['per_output'].items():
        lines += [f'## Output `{name}`', '',
                  f"Baseline: {p['baseline']['method']} na={p['baseline']['na']} "
                  f"nb={p['baseline']['nb']} d={p['baseline']['d']} at "
                  f"{p['baseline']['model_rate_hz']:.4g} Hz.", '',
                  '| candidate block | training NRMSE | information criterion |',
                  '|---|---|---|',
                  f"| none (linear) | {p['training_nrmse_baseline']:.4f} | "
                  f"{p['information_criterion_none']:.1f} |"]
        for _, c in sorted(p['candidates'].items(),
                           key=lambda kv: kv[1]['information_criterion']):
            lines.append(f"| {c['variant']} | {nrmse_cell(c['training_nrmse'])} | "
                         f"{c['information_criterion']:.1f} |")
        if p['parameters']:
            lines += ['', 'Chosen block: `' + json.dumps(p['parameters'])[:400] + '`']
        if name in files:
            lines += ['', f'![held-out response of {name}]({files[name]})']
        lines.append('')
    return '\n'.join(lines)
