"""The maRTHS benchmark through the ROS 2 node graph: ``rths bench marths --via graph``.

The three nodes run the benchmark's loop with the nominal plant (docs/marths.md):

* numerical node: ``model: marths`` (:class:`rths_numerical.marths.MarthsSubstructure`: the
  benchmark's numerical substructure, the two load cells' axial forces in, the two target
  strokes out through the coupler), the record exactly as the offline loop reads it;
* compensator node: ``none`` as the identity filter, ``mimo`` as the coupled 2 x 2 FIR
  (``coupled_taps``, :class:`rths_compensator.filters.CoupledFir`), ``decentralised_fir``
  as the same with each actuator's own FIR on the diagonal;
* bridge: ``backend: simulated_rig`` with ``config/rig_two_actuators.yaml`` (per-actuator
  limits, the coupler), the nominal control plant, the benchmark's sensor noise.

The bag records every actuator's command, measured stroke and axial force.  The same
controller (identified once) also runs offline (:func:`rths_bench.marths.run_benchmark`,
nominal plant) and the summary gives both J1-J10 and their largest relative difference
(``j_within_5pct`` is false too when the bridge's safety intervened: ``bridge_fault``).
Timing: the graph's measurement of step k answers command k, so the offline loop's
``measured(k)`` (sampled at the start of sample k) is the graph's measurement of step
k - 1 (:func:`rths_bench.rths_benchmark.sampled_at_start`).
"""

import json
import os
import time

import numpy as np

from . import marths as mb
from .bench_loop import machine_info
from .rths_benchmark import (
    BENCHMARK_SCHEME,
    RT_WATCHDOG_STEPS,
    _log,
    run_node_graph,
    sampled_at_start,
    write_at2,
)

#: Controllers the node graph runs (the adaptive ones per actuator would need each
#: actuator's own plant in the compensator node: not there yet).
GRAPH_CONTROLLERS = ('none', 'decentralised_fir', 'mimo')
#: The largest relative difference of a J-value between the graph and the offline run.
J_TOLERANCE = 0.05
#: Realtime: the bridge watchdog's consecutive misses (~10 ms at 1024 Hz, as the single-
#: actuator benchmark's 41 at 4096 Hz).
WATCHDOG_STEPS_1024 = max(1, round(RT_WATCHDOG_STEPS * 1024 / 4096))


def rig_file() -> str:
    """Return the example two-actuator rig file (``config/rig_two_actuators.yaml``)."""
    # lazy: rths_bringup pulls the launcher; only a graph run needs the config directory
    from rths_bringup.commands import default_config_dir
    return str(default_config_dir() / 'rig_two_actuators.yaml')


def build_controller(name: str, cfg: dict, log=_log, options: dict = None):
    """Return ``(offline controller for one run, coupled taps (2, 2, n) or None)``.

    Refuses a controller the compensator node cannot run (ValueError naming the choices).
    """
    if name not in GRAPH_CONTROLLERS:
        raise ValueError(f'--controller {name!r} does not run through the node graph yet; use '
                         f'{", ".join(GRAPH_CONTROLLERS)} (the adaptive ones run offline only)')
    ctrl = mb.make_controller(name, cfg, 1, options, log=log)
    if name == 'none':
        return ctrl, None
    if name == 'mimo':
        return ctrl, np.asarray(ctrl.taps, float)
    n = max(b.size for b in ctrl.b)
    if any(a.size for a in ctrl.a):
        raise ValueError('--controller decentralised_fir: a designed filter has a denominator; '
                         'the coupled FIR carries FIR taps only')
    taps = np.zeros((2, 2, n))
    for i, b in enumerate(ctrl.b):
        taps[i, i, :b.size] = b
    return ctrl, taps


def graph_params(cfg: dict, record_at2: str, taps, seed: int, rig: str) -> dict:
    """Params of the three nodes (``numerical``, ``compensator``, ``bridge``)."""
    fs = float(cfg['fs_hz']['value'])
    numerical = {'model': 'marths', 'fs_hz': fs, 'record': record_at2, 'scale': 1.0,
                 'duration_s': 0.0, 'record_resample': False, 'record_remove_mean': False,
                 'record_baseline': False}
    compensator = {'scheme': 'identity', 'fs_hz': fs, 'taps': [1.0], 'denominator': [1.0]}
    if taps is not None:
        compensator.update(scheme=BENCHMARK_SCHEME,
                           coupled_taps=[float(v) for v in np.ravel(taps)])
    bridge = {'backend': 'simulated_rig', 'rig_file': rig, 'fs_hz': fs,
              'rig_plant_draw': 0, 'rig_noise_seed': int(seed), 'rig_sensor_noise': 1}
    return {'numerical': numerical, 'compensator': compensator, 'bridge': bridge}


def graph_histories(run: dict, cfg: dict, reference: dict) -> dict:
    """Return the offline loop's histories (one run, strokes in mm) of a graph run."""
    # lazy: bagio pulls rosbag2_py; only reading a graph run's bag needs it
    from rths_common import bagio, topics
    hist = run['history']
    n = len(hist['command'])
    meas = bagio.step_arrays(run['bag'], topics.MEASUREMENT, ('displacement', 'applied'))
    measured = np.full((n, 2), np.nan)
    applied = np.full((n, 2), np.nan)
    inside = meas['step'] < n
    measured[meas['step'][inside]] = meas['displacement'][inside, :2]
    applied[meas['step'][inside]] = meas['applied'][inside, :2]
    coupler = mb.rig_coupler(cfg)
    m0 = np.column_stack([sampled_at_start(measured[:, i]) for i in range(2)])
    x_hat, th_hat = coupler.dofs(m0.T, iterations=2)
    dofs = {k: v - 1 for k, v in cfg['reference']['dofs'].items()}
    d = hist['displacements']

    def col(a):
        return np.asarray(a, float)[:, None]

    faults = [(msg.step, msg.fault) for _, msg in bagio.read_topic(run['bag'], topics.STATUS)
              if msg.node == 'bridge' and msg.fault]
    return {'target': 1000.0 * hist['command'][:, None], 'measured': 1000.0 * m0[:, None],
            'bridge_fault': f'step {faults[0][0]}: {faults[0][1]}' if faults else '',
            'command': 1000.0 * applied[:, None],
            'x_hat': col(1000.0 * x_hat), 'theta_hat': col(th_hat),
            'x_num': col(1000.0 * hist['x_num']), 'theta_num': col(hist['theta_num']),
            'x2': col(d[:, dofs['x_2nd']]), 'th2': col(d[:, dofs['theta_2nd']]),
            'x3': col(d[:, dofs['x_3rd']]), 'th3': col(d[:, dofs['theta_3rd']]),
            'reference': reference,
            'steps_recorded': int(np.sum(np.all(np.isfinite(measured), axis=1)))}


def relative_differences(graph: dict, offline: dict) -> dict:
    """Per J the largest ``|graph - offline| / |offline|`` over its entries.

    Equal values (also two infinite ones: a criterion against a silent reference, e.g.
    the first 5 s of the benchmark's El Centro record) differ by 0; a non-finite
    difference otherwise is inf.
    """
    out = {}
    for name in mb.J_NAMES:
        g, o = np.asarray(graph[name], float), np.asarray(offline[name], float)
        with np.errstate(invalid='ignore', divide='ignore'):
            rel = np.where(g == o, 0.0, np.abs(g - o) / np.abs(o))
        rel = np.where(np.isfinite(rel), rel, np.inf)
        out[name] = round(float(np.max(rel)), 4)
    return out


def run_graph(controller: str = 'none', record: str = 'elcentro', duration_s: float = None,
              data_dir: str = None, out_dir: str = '.', mode: str = 'lockstep',
              seed: int = 2023, options: dict = None, log=_log) -> dict:
    """Run ``controller`` on the nominal plant through the node graph and offline; the summary."""
    t0, c0 = time.perf_counter(), time.process_time()
    cfg = mb.load_config()
    fs = float(cfg['fs_hz']['value'])
    ctrl, taps = build_controller(controller, cfg, log, options)
    scale = cfg['record']['scale'] if record == 'elcentro' else None
    t, ag = mb.ground_acceleration(record, fs, scale, data_dir, duration_s)
    os.makedirs(out_dir, exist_ok=True)
    at2 = write_at2(os.path.join(out_dir, 'record.AT2'), t, ag, dt_decimals=10)
    log(f'maRTHS via graph ({mode}): {controller}, {record}, {len(ag)} samples at {fs:g} Hz; '
        'first the offline loop (nominal plant)')
    offline = mb.run_benchmark(controller, record, 0, seed, duration_s, data_dir, cfg,
                               log=log, built=ctrl)
    params = graph_params(cfg, at2, taps, seed + 1, rig_file())
    run = run_node_graph(params, os.path.join(out_dir, 'graph'), log, mode,
                         watchdog_steps=WATCHDOG_STEPS_1024)
    h = graph_histories(run, cfg, offline['_histories']['reference'])
    nominal = mb.criteria(h, 0, fs)
    volts = np.nanmax(np.abs(mb.command_volts(cfg, h['command'][:, 0])), axis=0)
    diffs = relative_differences(nominal, offline['nominal'])
    summary = {
        'controller': controller, 'via': 'graph', 'mode': mode,
        'nominal': nominal, 'offline_nominal': offline['nominal'],
        'j_relative_difference': diffs,
        'j_max_relative_difference': max(diffs.values()),
        'j_within_5pct': bool(max(diffs.values()) <= J_TOLERANCE and not h['bridge_fault']),
        'max_command_v': [float(v) for v in volts],
        'realizable': bool(np.all(volts <= cfg['channels']['sat_limit_v'])),
        'steps': len(ag), 'steps_recorded': h['steps_recorded'],
        'samples_lost': len(ag) - h['steps_recorded'],
        'bridge_fault': h['bridge_fault'],
        'settings': {'record': record, 'scale': scale, 'fs_hz': fs, 'seed': seed,
                     'controller': ctrl.describe(), 'bag': str(run['bag']),
                     'rig_file': params['bridge']['rig_file'],
                     'numerical_model': 'marths (far-end moment of the frame left out)',
                     'total_s': round(time.perf_counter() - t0, 2),
                     'cpu_s': round(time.process_time() - c0, 2),
                     'load_average_1min': round(os.getloadavg()[0], 2)},
    }
    if 'realtime' in run:
        summary['realtime'] = run['realtime']
    summary['date'] = time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())
    summary['machine'] = machine_info()
    summary['_histories'] = h
    return summary


def table_markdown(summary: dict) -> str:
    """J1-J10 of the graph run beside the offline run's, as a markdown table."""
    lines = [f"maRTHS benchmark through the node graph ({summary['mode']}), controller "
             f"{summary['controller']}, nominal plant", '',
             '| J | graph | offline | largest relative difference |', '|---|---|---|---|']
    for name in mb.J_NAMES:
        g = ', '.join(f'{v:.2f}' for v in summary['nominal'][name])
        o = ', '.join(f'{v:.2f}' for v in summary['offline_nominal'][name])
        lines.append(f"| {name} | {g} | {o} | {summary['j_relative_difference'][name]:.4f} |")
    lines += ['', f"J within 5 % of offline: {summary['j_within_5pct']}; samples lost from the "
              f"bag: {summary['samples_lost']} of {summary['steps']}"]
    if summary.get('bridge_fault'):
        lines.append(f"the bridge's safety intervened (the offline loop has no limits), "
                     f"{summary['bridge_fault']}")
    rt = summary.get('realtime')
    if rt:
        lines.append(f"realtime: deadline misses {rt['deadline_miss_pct']} %, late or missed "
                     f"{rt['late_or_missed_pct']} % (floor {rt['floor_late_pct']} %), recorder "
                     f"loss {rt['recorder_loss']}, load average {rt['load_average_1min']}")
    return '\n'.join(lines) + '\n'


def write_outputs(summary: dict, directory: str) -> list:
    """Write ``summary.json`` and ``table.md`` (non-finite numbers as null)."""
    os.makedirs(directory, exist_ok=True)
    data = mb._finite({k: v for k, v in summary.items() if not k.startswith('_')})
    files = [os.path.join(directory, 'summary.json'), os.path.join(directory, 'table.md')]
    with open(files[0], 'w') as fh:
        json.dump(data, fh, indent=1, allow_nan=False)
        fh.write('\n')
    with open(files[1], 'w') as fh:
        fh.write(table_markdown(summary))
    return files
