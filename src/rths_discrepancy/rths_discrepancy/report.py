"""Outputs of the discrepancy workflow: result.json, updated_model.yaml, report.md, PNG plots.

Every file is written to a temporary name and renamed, so an error never
leaves a half-written result behind.
"""

import json
import os

import numpy as np
import yaml


def _atomic_write(path, text):
    tmp = f'{path}.tmp'
    with open(tmp, 'w') as fh:
        fh.write(text)
    os.replace(tmp, path)


def _plots(out_dir, ctx, after_pred):
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib
    matplotlib.use('Agg')
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib.pyplot as plt
    t = np.arange(ctx.n) / ctx.fs
    te = ctx.test
    r0 = ctx.y - ctx.y_nom
    r1 = ctx.y - after_pred
    files = {}
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax[0].plot(t, ctx.y, lw=0.6, label='measured')
    ax[0].plot(t, ctx.y_nom, lw=0.6, label='nominal model')
    ax[0].plot(t, after_pred, lw=0.6, ls='--', label='updated model')
    ax[0].set_ylabel('output [m]')
    ax[0].legend(loc='upper right', fontsize=8)
    ax[1].plot(t, np.where(te, r0, np.nan), lw=0.6, label='before (held-out)')
    ax[1].plot(t, np.where(te, r1, np.nan), lw=0.6, label='after (held-out)')
    ax[1].set_ylabel('residual [m]')
    ax[1].set_xlabel('time [s]')
    ax[1].legend(loc='upper right', fontsize=8)
    fig.tight_layout()
    files['residuals'] = 'residuals.png'
    fig.savefig(os.path.join(out_dir, files['residuals'] + '.tmp.png'), dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4))
    for r, lab in ((r0, 'before'), (r1, 'after')):
        spec = np.abs(np.fft.rfft(r - r.mean())) ** 2 / ctx.n
        f = np.fft.rfftfreq(ctx.n, 1.0 / ctx.fs)
        ax.loglog(f[1:], spec[1:] + 1e-300, lw=0.5, label=f'residual {lab}')
    ax.axhline(ctx.sigma2, color='k', ls=':', label='noise floor')
    ax.set_xlabel('frequency [Hz]')
    ax.set_ylabel('periodogram [m^2]')
    ax.legend(fontsize=8)
    fig.tight_layout()
    files['spectrum'] = 'residual_spectrum.png'
    fig.savefig(os.path.join(out_dir, files['spectrum'] + '.tmp.png'), dpi=110)
    plt.close(fig)
    st = ctx.states
    fig, ax = plt.subplots(1, 2, figsize=(9, 4))
    res = ctx.e_r if ctx.force_rows else r0
    lab = 'restoring-force residual [N]' if ctx.force_rows else 'output residual [m]'
    ax[0].plot(st['x'], res, ',', alpha=0.5)
    ax[0].set_xlabel('displacement [m]')
    ax[0].set_ylabel(lab)
    ax[1].plot(st['v'], res, ',', alpha=0.5)
    ax[1].set_xlabel('velocity [m/s]')
    fig.suptitle('state view of the residual (restoring-force-surface style)')
    fig.tight_layout()
    files['state'] = 'residual_state.png'
    fig.savefig(os.path.join(out_dir, files['state'] + '.tmp.png'), dpi=110)
    plt.close(fig)
    for name in files.values():
        os.replace(os.path.join(out_dir, name + '.tmp.png'), os.path.join(out_dir, name))
    return files


def markdown(result, files) -> str:
    """Return the report.md text."""
    lines = [f"# Discrepancy report ({result['scenario']})", '',
             f"**Effect: `{result['effect']}`**", '']
    for name, par in result['parameters'].items():
        (sym, val), = [(k, v) for k, v in par.items() if k != 'unit']
        lines.append(f"- {name}: {sym} = {val:.5g} {par['unit']}")
    if 'unexplained_note' in result:
        lines.append(f"- {result['unexplained_note']}")
    if 'alignment_s' in result:
        lines += ['', f"Model-measurement alignment (a DAQ timing convention, fitted as a "
                  f"nuisance parameter, not an effect): {1e3 * result['alignment_s']:+.4f} ms "
                  f"= {result['alignment_samples']:+.2f} samples (band +-"
                  f"{result['alignment_band_samples']:g} samples; a lag outside it is a "
                  f"time_delay)."]
    lines += ['', '| held-out | NRMSE |', '|---|---|',
              f"| before (nominal, aligned) | {result['nrmse_before']:.5f} |",
              f"| after (updated model, re-simulated) | {result['nrmse_after']:.5f} |",
              f"| noise floor | {result['nrmse_noise']:.5f} |", '',
              f"gap closed: {result['gap_closed']:.3f}", '', '## Where the model disagrees', '']
    lines += [f'- {s}' for s in result['localization']['summary']]
    cov = result['coverage']
    lines += ['', f"Held-out amplitude coverage of the best candidate: effect rms ratio "
              f"{cov['effect_rms_ratio_heldout_to_train']:.2f}, amplitude ratio "
              f"{cov['amplitude_ratio_heldout_to_train']:.2f}"
              + ('' if cov['ok'] else ' (WARNING: held-out data do not cover the effect)'),
              '', '## Evidence: held-out NRMSE of every candidate', '',
              '| candidate | held-out NRMSE | score (noise units) |', '|---|---|---|']
    for k in sorted(result['candidates'], key=lambda k: result['candidates_score'][k]):
        lines.append(f"| {k} | {result['candidates'][k]:.5f} | "
                     f"{result['candidates_score'][k]:.2f} |")
    lines += ['']
    for key, title in (('residuals', 'Residual before/after'),
                       ('spectrum', 'Residual spectrum'), ('state', 'State view')):
        if key in files:
            lines += [f'## {title}', '', f'![{title}]({files[key]})', '']
    return '\n'.join(lines)


def write_outputs(out_dir, result, ctx, after_pred, plots=True):
    """Write result.json, updated_model.yaml, report.md (+ PNGs) into ``out_dir``."""
    os.makedirs(out_dir, exist_ok=True)
    files = _plots(out_dir, ctx, after_pred) if plots else {}
    _atomic_write(os.path.join(out_dir, 'updated_model.yaml'),
                  yaml.safe_dump(result['updated_model'], sort_keys=False))
    _atomic_write(os.path.join(out_dir, 'report.md'), markdown(result, files))
    _atomic_write(os.path.join(out_dir, 'result.json'), json.dumps(result, indent=2))
