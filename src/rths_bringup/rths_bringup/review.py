"""Review of a recorded run, rebuilt from its bag alone."""

import numpy as np

from rths_bringup import bagio
from rths_common import topics

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
    """Per-topic step indices and arrays of a bag: ``{topic: {'step': [...], field: [[...]]}}``."""
    data = {t: {'step': [], 'values': []} for t in STEP_TOPICS}
    status = {}
    for topic, _, msg in bagio.read_messages(bag, list(STEP_TOPICS) + [topics.STATUS]):
        if topic == topics.STATUS:
            s = status.setdefault(msg.node, {'step': [], 'compute_us': [], 'latency_us': [],
                                             'misses': 0, 'safety_state': [], 'faults': []})
            s['step'].append(msg.step)
            s['compute_us'].append(msg.compute_us)
            s['latency_us'].append(msg.latency_us)
            s['misses'] = max(s['misses'], msg.deadline_misses)
            s['safety_state'].append(msg.safety_state)
            if msg.fault:
                s['faults'].append(f'step {msg.step}: {msg.fault}')
            continue
        field, _ = STEP_TOPICS[topic]
        data[topic]['step'].append(msg.step)
        data[topic]['values'].append(np.asarray(getattr(msg, field), dtype=float))
    return {'steps': data, 'status': status}


def _pct(values, q):
    values = [v for v in values if v >= 0]
    return round(float(np.percentile(values, q)), 1) if values else None


def loop_summary(bag) -> dict:
    """The printed/JSON summary of a run: steps per topic, extremes, per-node timing."""
    loop = read_loop(bag)
    summary = {'bag': str(bag)}
    for topic, (field, unit) in STEP_TOPICS.items():
        entry = step_check(loop['steps'][topic]['step'])
        values = loop['steps'][topic]['values']
        if values:
            entry[f'max_abs_{field}_{unit}'] = float(np.max(np.abs(np.concatenate(values))))
        summary[topic] = entry
    for node, s in sorted(loop['status'].items()):
        summary[f'status {node}'] = {
            'steps': len(s['step']),
            'compute_us_p50': _pct(s['compute_us'], 50),
            'compute_us_p99': _pct(s['compute_us'], 99),
            'latency_us_p50': _pct(s['latency_us'], 50),
            'latency_us_p99': _pct(s['latency_us'], 99),
            'deadline_misses': s['misses'],
            'final_safety_state': s['safety_state'][-1] if s['safety_state'] else None,
            'faults': s['faults'][:5],
        }
    return summary
