"""What a finished (or interrupted) study shows: summary.json, plots and report.html.

* ``summary.json``: counts, each metric's distribution per group (controller and
  record: n, mean, std, min, 5 %, median, 95 %, max), the worst runs of each metric
  (largest value: every metric of the scenarios is an error or a response, smaller is
  better), the grid's best point per metric and group, and the failed runs' errors.
* ``distributions.png``: a histogram of each metric, one colour per group.
* ``worst.png``: each metric's values sorted (the tail on the right), the worst runs
  labelled with their index.
* ``parameters.png`` (random draws and lists): the first metric against each parameter.
* ``surface_<group>.png`` (a grid of two parameters): each metric as a contour map;
  ``grid_<group>.png`` (a grid of one): each metric along the axis.
* ``report.html``: the tables and every plot in one self-contained page.
"""

import base64
import html
import json
import math
from pathlib import Path

import numpy as np

from .scenarios import get

#: Worst runs listed per metric.
N_WORST = 5
_STYLE = ('body{font-family:sans-serif;max-width:64em;margin:1em auto;color:#222}'
          'table{border-collapse:collapse;margin:.5em 0 1.5em}'
          'th,td{border:1px solid #bbb;padding:.25em .6em;text-align:right}'
          'th:first-child,td:first-child{text-align:left}'
          'figure{margin:1em 0}img{max-width:100%}figcaption{font-size:.9em;color:#555}')


def _group(row) -> str:
    parts = [str(row[k]) for k in ('controller', 'record') if row.get(k) is not None]
    return ' / '.join(parts) or 'all'


def _float_metrics(spec) -> list:
    kinds = get(spec.kind).metrics
    return [m for m in spec.metrics if kinds[m] == 'float']


def _stats(values) -> dict:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], float)
    if not v.size:
        return {'n': 0}
    q = np.percentile(v, [5, 50, 95])
    return {'n': int(v.size), 'mean': float(v.mean()), 'std': float(v.std()),
            'min': float(v.min()), 'p05': float(q[0]), 'median': float(q[1]),
            'p95': float(q[2]), 'max': float(v.max())}


def summarise(spec, rows: list, session: dict | None = None) -> dict:
    """Return the ``summary.json`` content of ``rows`` (the store's table as dicts)."""
    ok = [r for r in rows if r['status'] == 'ok']
    groups = sorted({_group(r) for r in rows})
    out = {'study': spec.study, 'scenario': spec.kind, 'spec': spec.source,
           'layout': spec.layout, 'parameters': spec.parameter_names,
           'runs': len(spec.runs()), 'rows': len(rows), 'ok': len(ok),
           'errors': len(rows) - len(ok), 'table': 'runs/ (Parquet, one row per run)',
           'session': session or {}, 'metrics': {}, 'worst': {}, 'failures': []}
    kinds = get(spec.kind).metrics
    for m in spec.metrics:
        per = {}
        for g in groups:
            vals = [r[m] for r in ok if _group(r) == g]
            per[g] = ({'n': len(vals), 'true': int(sum(bool(v) for v in vals))}
                      if kinds[m] == 'bool' else _stats(vals))
        out['metrics'][m] = per
    for m in _float_metrics(spec):
        ranked = sorted((r for r in ok if r[m] is not None and math.isfinite(r[m])),
                        key=lambda r: r[m], reverse=True)[:N_WORST]
        out['worst'][m] = [{'index': r['index'], 'key': r['key'], 'group': _group(r),
                            'value': r[m], **{p: r[p] for p in spec.parameter_names}}
                           for r in ranked]
    if spec.layout == 'grid':
        out['grid_best'] = {m: {g: _best(ok, m, g, spec.parameter_names) for g in groups}
                            for m in _float_metrics(spec)}
    out['failures'] = [{'index': r['index'], 'key': r['key'], 'error': r['error']}
                       for r in rows if r['status'] != 'ok'][:50]
    return out


def _best(rows, metric, group, names):
    cand = [r for r in rows if _group(r) == group and r[metric] is not None
            and math.isfinite(r[metric])]
    if not cand:
        return None
    r = min(cand, key=lambda r: r[metric])
    return {'value': r[metric], **{p: r[p] for p in names}}


# ----------------------------------------------------------------------------- plots
def _pyplot():
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib
    matplotlib.use('Agg')
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib.pyplot as plt
    return plt


def _grid_axes(n):
    cols = min(3, n)
    return cols, int(math.ceil(n / cols))


def plot_distributions(spec, rows, path) -> Path | None:
    """Histogram of each float metric, one colour per group."""
    metrics = _float_metrics(spec)
    ok = [r for r in rows if r['status'] == 'ok']
    if not metrics or not ok:
        return None
    plt = _pyplot()
    cols, nrows = _grid_axes(len(metrics))
    fig, axes = plt.subplots(nrows, cols, figsize=(4 * cols, 2.8 * nrows), squeeze=False)
    groups = sorted({_group(r) for r in ok})
    for ax, m in zip(axes.ravel(), metrics, strict=False):
        for g in groups:
            v = np.asarray([r[m] for r in ok if _group(r) == g and r[m] is not None], float)
            v = v[np.isfinite(v)]
            if v.size:
                ax.hist(v, bins=min(40, max(5, v.size // 10)), alpha=0.55, label=g)
        ax.set_title(m, fontsize=9)
    for ax in axes.ravel()[len(metrics):]:
        ax.axis('off')
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f'{spec.study}: distribution of each metric over {len(ok)} runs')
    return _save(fig, path)


def plot_worst(spec, rows, path) -> Path | None:
    """Each metric's values sorted per group, the worst runs labelled by index."""
    metrics = _float_metrics(spec)
    ok = [r for r in rows if r['status'] == 'ok']
    if not metrics or not ok:
        return None
    plt = _pyplot()
    cols, nrows = _grid_axes(len(metrics))
    fig, axes = plt.subplots(nrows, cols, figsize=(4 * cols, 2.8 * nrows), squeeze=False)
    for ax, m in zip(axes.ravel(), metrics, strict=False):
        for g in sorted({_group(r) for r in ok}):
            pts = sorted(((r[m], r['index']) for r in ok if _group(r) == g
                          and r[m] is not None and math.isfinite(r[m])))
            if not pts:
                continue
            frac = (np.arange(len(pts)) + 1) / len(pts)
            ax.plot(frac, [p[0] for p in pts], label=g)
            for val, idx in pts[-3:]:
                ax.annotate(str(idx), (1.0, val), fontsize=6, xytext=(2, 0),
                            textcoords='offset points')
        ax.set_title(m, fontsize=9)
        ax.set_xlabel('fraction of runs', fontsize=8)
    for ax in axes.ravel()[len(metrics):]:
        ax.axis('off')
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f'{spec.study}: sorted values; the worst runs (right end) by index')
    return _save(fig, path)


def plot_parameters(spec, rows, path) -> Path | None:
    """Plot the first float metric against each varied parameter (random draws, lists)."""
    metrics = _float_metrics(spec)
    names = [n for n in spec.parameter_names
             if all(isinstance(r[n], (int, float)) for r in rows)]
    ok = [r for r in rows if r['status'] == 'ok']
    if not metrics or not names or not ok:
        return None
    plt = _pyplot()
    m = metrics[0]
    fig, axes = plt.subplots(1, len(names), figsize=(3.6 * len(names), 3), squeeze=False)
    for ax, n in zip(axes[0], names, strict=True):
        for g in sorted({_group(r) for r in ok}):
            sel = [r for r in ok if _group(r) == g]
            ax.plot([r[n] for r in sel], [r[m] for r in sel], '.', ms=3, label=g)
        ax.set_xlabel(n)
        ax.set_ylabel(m)
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(f'{spec.study}: {m} against each parameter')
    return _save(fig, path)


def plot_grid(spec, rows, directory) -> list:
    """Surfaces (two grid axes) or curves (one) of each metric, one file per group."""
    axes_names = list(spec.axes)
    metrics = _float_metrics(spec)
    ok = [r for r in rows if r['status'] == 'ok']
    if spec.layout != 'grid' or len(axes_names) not in (1, 2) or not metrics or not ok:
        return []
    plt = _pyplot()
    files = []
    for i, g in enumerate(sorted({_group(r) for r in ok})):
        sel = {tuple(r[a] for a in axes_names): r for r in ok if _group(r) == g}
        cols, nrows = _grid_axes(len(metrics))
        fig, axs = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.3 * nrows), squeeze=False)
        for ax, m in zip(axs.ravel(), metrics, strict=False):
            if len(axes_names) == 1:
                xs = spec.axes[axes_names[0]]
                ax.plot(xs, [sel[(x,)][m] if (x,) in sel else np.nan for x in xs], '.-')
                ax.set_xlabel(axes_names[0])
            else:
                xs, ys = spec.axes[axes_names[0]], spec.axes[axes_names[1]]
                z = np.array([[sel[(x, y)][m] if (x, y) in sel and sel[(x, y)][m] is not None
                               else np.nan for x in xs] for y in ys], float)
                if len(xs) > 1 and len(ys) > 1 and np.isfinite(z).any():
                    cs = ax.contourf(xs, ys, np.ma.masked_invalid(z), 30)
                    fig.colorbar(cs, ax=ax)
                ax.set_xlabel(axes_names[0])
                ax.set_ylabel(axes_names[1])
            ax.set_title(m, fontsize=9)
        for ax in axs.ravel()[len(metrics):]:
            ax.axis('off')
        fig.suptitle(f'{spec.study}: {g}')
        name = ('surface' if len(axes_names) == 2 else 'grid') + f'_{i}.png'
        files.append(_save(fig, Path(directory) / name))
    return files


def _save(fig, path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=70)
    _pyplot().close(fig)
    return Path(path)


# ----------------------------------------------------------------------------- page
def _table(caption, header, rows) -> str:
    cells = ''.join(f'<th>{html.escape(str(h))}</th>' for h in header)
    body = ''.join('<tr>' + ''.join(f'<td>{html.escape(_fmt(c))}</td>' for c in row) + '</tr>'
                   for row in rows)
    return f'<h2>{html.escape(caption)}</h2>\n<table><tr>{cells}</tr>{body}</table>\n'


def _fmt(value) -> str:
    if isinstance(value, float):
        return f'{value:.5g}'
    return '-' if value is None else str(value)


def render(summary: dict, images: dict) -> str:
    """Return the page: counts, each metric's spread, the worst runs, failures, plots."""
    s = summary
    title = f"Study {s['study']} ({s['scenario']}): {s['ok']} of {s['runs']} runs ok"
    page = _table('Runs', ('runs', 'rows', 'ok', 'failed', 'workers', 'wall [s]'),
                  [(s['runs'], s['rows'], s['ok'], s['errors'],
                    s['session'].get('workers', '-'), s['session'].get('wall_s', '-'))])
    stats = []
    for m, per in s['metrics'].items():
        for g, st in per.items():
            values = [st.get(k) for k in ('mean', 'std', 'min', 'p05', 'median', 'p95', 'max')]
            if 'true' in st:
                values[0] = st['true']
            stats.append((m, g, st.get('n'), *values))
    page += _table('Metrics (bool metrics: mean column = runs true)',
                   ('metric', 'group', 'n', 'mean', 'std', 'min', '5 %', 'median', '95 %',
                    'max'), stats)
    worst = [(m, w['index'], w['group'], w['value'],
              ', '.join(f'{p}={_fmt(w[p])}' for p in s['parameters']))
             for m, ws in s['worst'].items() for w in ws[:3]]
    page += _table('Worst runs (largest values)', ('metric', 'run', 'group', 'value',
                                                   'parameters'), worst)
    if s['failures']:
        page += _table('Failed runs', ('run', 'key', 'error'),
                       [(f['index'], f['key'], f['error']) for f in s['failures']])
    figures = ''.join(
        f'<figure><img alt="{html.escape(n)}" src="data:image/png;base64,'
        f'{base64.b64encode(d).decode("ascii")}"><figcaption>{html.escape(n)}</figcaption>'
        '</figure>\n' for n, d in images.items())
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>'
            f'{html.escape(title)}</title><style>{_STYLE}</style></head>\n<body>\n<h1>'
            f'{html.escape(title)}</h1>\n<p>table: <code>runs/</code> (Parquet), spec: '
            f'<code>spec.yaml</code>, log: <code>study.log</code></p>\n{page}{figures}'
            '</body></html>\n')


def write_report(spec, store, session: dict | None = None, plots: bool = True) -> list:
    """Write summary.json (and the plots and report.html) into the study directory."""
    rows = store.table().to_pylist()
    summary = summarise(spec, rows, session)
    directory = store.dir
    files = [directory / 'summary.json']
    _write_json(files[0], summary)
    if not plots:
        return files
    images = [plot_distributions(spec, rows, directory / 'distributions.png'),
              plot_worst(spec, rows, directory / 'worst.png')]
    if spec.layout in ('random', 'list'):
        images.append(plot_parameters(spec, rows, directory / 'parameters.png'))
    images += plot_grid(spec, rows, directory)
    images = [p for p in images if p]
    page = directory / 'report.html'
    page.write_text(render(summary, {p.name: p.read_bytes() for p in images}),
                    encoding='utf-8')
    return files + images + [page]


def _write_json(path, data):
    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list):
            return [clean(x) for x in v]
        return v
    tmp = Path(path).with_suffix('.json.tmp')
    tmp.write_text(json.dumps(clean(data), indent=1) + '\n')
    tmp.replace(path)
