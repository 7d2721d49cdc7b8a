"""``rths bench adaptive --step-cost``: the per-step cost of every compensator method.

What the compensator node runs per step, timed at each rate the project runs in real
time, with the taps each method gets there:

* 1024 Hz: the project's default run (``config/compensator.yaml``, the 400-tap WLS FIR,
  and its ``config/plant.yaml``; ``rls_fir`` adapts a 16-tap correction of it);
* 4096 Hz: the RTHS benchmark through the node graph (``rths bench rths-benchmark --via
  graph``): its identification and 200-tap LS FIR (``timing='graph'``), ``rls_fir`` on
  the FIR's design plant, ``ats``/``amb`` on the identified ARX model.

Each method runs in closed loop on its plant model (the identified ARX, sensor noise
2 um) following a BLWN target (0-10 Hz, 5.08 mm peak): ``method.step`` is timed per
step (``step_us_*``), and so is the node's core (``CompensatorCore.step`` in realtime
mode with the measurement of the previous step: ``core_step_us_*``).  The first 0.5 s
(start-up, frozen) are left out.  Timing is wall time (``time.perf_counter_ns``) on a
possibly loaded machine: the JSON records the load average and an empty call's cost.
"""

import json
import os
import platform
import subprocess
import sys
import tempfile
import time

import numpy as np

from rths_bringup.commands import default_config_dir
from rths_common.progress import Progress
from rths_compensator.adaptive import make_method
from rths_compensator.core import CompensatorCore
from rths_compensator.design import Design
from rths_compensator.filters import CausalFilter
from rths_compensator.identification import load_plant
from rths_compensator.methods import METHODS
from rths_compensator.params import load_compensator_params
from rths_numerical.signals import blwn

from .bench_adaptive import _floor_us
from .rths_benchmark import identify_and_design, write_method_plant

RATES = (1024, 4096)
WARMUP_S = 0.5
NOISE_M = 2e-6


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def _config_1024():
    """``(design, plant, plant_path, info)`` of the project's default run (config/)."""
    config = default_config_dir()
    params = load_compensator_params(config / 'compensator.yaml')
    plant_path = config / str(params['provenance'].get('plant', 'plant.yaml'))
    design = Design(str(params['scheme']), np.asarray(params['taps'], float),
                    np.asarray(params['denominator'], float), float(params['fs_hz']))
    plant = load_plant(plant_path)
    info = {'source': f'config/compensator.yaml and config/{plant_path.name}',
            'scheme': design.scheme, 'taps': int(design.taps.size)}
    names = ('rls_fir', 'ats', 'amb')
    return design, dict.fromkeys(names, plant), dict.fromkeys(names, plant_path), info


def _benchmark_4096(workdir, log):
    """Return the RTHS benchmark's graph design at 4096 Hz and each method's plant."""
    design, info = identify_and_design(timing='graph', log=log)
    paths = {name: write_method_plant(name, info, 4096.0, os.path.join(workdir, f'{name}.yaml'))
             for name in ('rls_fir', 'ats', 'amb')}
    plants = {name: load_plant(path) for name, path in paths.items()}
    summary = {'source': 'rths bench rths-benchmark --via graph: identify_and_design('
                         "timing='graph')", 'scheme': design.scheme,
               'taps': int(design.taps.size), 'arx': info['arx']}
    return design, plants, paths, summary


class _PlantModel:
    """The method's own plant model as the specimen: ``y_k = T(q) u_k`` plus noise."""

    def __init__(self, plant, seed):
        self.filter = CausalFilter(np.r_[np.zeros(plant.d), plant.b], plant.a)
        self.noise = NOISE_M * np.random.default_rng(seed).standard_normal(1 << 20)
        self.k = 0

    def step(self, u):
        self.k += 1
        return self.filter.step(u) + float(self.noise[self.k % self.noise.size])


def _percentiles(ns, skip):
    us = np.asarray(ns[skip:], float) / 1e3
    return round(float(np.median(us)), 2), round(float(np.percentile(us, 99)), 2)


def time_method(name, design, plant, fs_hz, target, seed=1):
    """Time ``method.step`` per step in closed loop; return p50/p99 [us] and the states."""
    entry = METHODS.entry(name)
    method = make_method(name, design, plant if entry.adaptive else None)
    sim = _PlantModel(plant, seed)
    n = target.size
    ns = np.zeros(n)
    states = {}
    prev = None
    clock = time.perf_counter_ns
    for k in range(n):
        x = float(target[k])
        t0 = clock()
        u = method.step(x, prev)
        ns[k] = clock() - t0
        prev = sim.step(u)
        state = method.status.state
        states[state] = states.get(state, 0) + 1
    p50, p99 = _percentiles(ns, int(WARMUP_S * fs_hz))
    return {'step_us_p50': p50, 'step_us_p99': p99, 'states': states}


def time_core(name, design, plant, plant_path, fs_hz, target, seed=1):
    """Time the node's core step (realtime, measurement k-1 in); return p50/p99 [us]."""
    params = {'scheme': design.scheme, 'taps': design.taps.tolist(),
              'denominator': design.denominator.tolist(), 'fs_hz': float(fs_hz),
              'method': name}
    if plant_path:
        params['plant'] = str(plant_path)
    core = CompensatorCore(params, realtime=True)
    core.warm_up(1)
    sim = _PlantModel(plant, seed)
    n = target.size
    ns = np.zeros(n)
    clock = time.perf_counter_ns
    for k in range(n):
        x = np.array([target[k]])
        t0 = clock()
        result = core.step(k, x)
        ns[k] = clock() - t0
        u = float(result.arrays[0][0])
        y = sim.step(u)
        if core.adaptive:
            core.measure(k, np.array([y]), np.array([u]))
    p50, p99 = _percentiles(ns, int(WARMUP_S * fs_hz))
    return {'core_step_us_p50': p50, 'core_step_us_p99': p99}


def _cpu_model():
    try:
        with open('/proc/cpuinfo', encoding='utf-8') as handle:
            for line in handle:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def _uptime():
    try:
        return subprocess.run(['uptime'], capture_output=True, text=True, timeout=5,
                              check=False).stdout.strip()
    except OSError:
        return ''


def run_step_cost(out_dir, duration_s=8.0, rates=RATES, seed=24, log=_log):
    """Time every method at every rate; write ``out_dir/summary.json``; return it."""
    if duration_s < 2.0 * WARMUP_S:
        raise ValueError(f'--step-cost-s {duration_s} s is too short; use >= {2 * WARMUP_S:g} s')
    unknown = [r for r in rates if r not in RATES]
    if unknown:
        raise ValueError(f'--step-cost-rates: {unknown[0]} Hz has no scenario; use '
                         f'{", ".join(map(str, RATES))}')
    os.makedirs(out_dir, exist_ok=True)
    names = METHODS.names()       # fir, the adaptive methods and pi_lead
    load = list(os.getloadavg())
    out = {'date': time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime()),
           'uptime_start': _uptime(), 'load_average_start': load,
           'machine': {'cpu': _cpu_model(), 'nproc': os.cpu_count(),
                       'loadavg': ' '.join(f'{v:.2f}' for v in load),
                       'kernel': platform.release(), 'python': platform.python_version(),
                       'numpy': np.__version__},
           'duration_s': float(duration_s), 'warmup_s': WARMUP_S, 'rates': {}}
    with tempfile.TemporaryDirectory(prefix='rths_step_cost_') as workdir:
        setups = {}
        for rate in rates:
            log(f'step cost: design at {rate} Hz')
            setups[rate] = (_config_1024() if rate == 1024 else _benchmark_4096(workdir, log))
        bar = Progress(len(rates) * len(names), 'bench adaptive --step-cost', 'methods')
        for rate in rates:
            design, plants, paths, info = setups[rate]
            fs = float(design.fs_hz)
            target = blwn(duration_s, fs, 10.0, 5.08e-3, np.random.default_rng(seed),
                          taper_s=0.2)
            block = {'design': info, 'methods': {}}
            for name in names:
                plant = plants.get(name, plants['ats'])   # fir, pi_lead: the ARX as the plant
                path = paths.get(name, '')
                row = time_method(name, design, plant, fs, target)
                row.update(time_core(name, design, plant, path, fs, target))
                block['methods'][name] = row
                with bar.hidden():
                    log(f'{rate:5d} Hz {name:8s} step p50 {row["step_us_p50"]:6.1f} us p99 '
                        f'{row["step_us_p99"]:6.1f} us; core p50 {row["core_step_us_p50"]:6.1f}'
                        f' us p99 {row["core_step_us_p99"]:6.1f} us; {row["states"]}')
                bar.advance()
            out['rates'][str(rate)] = block
        bar.close()
    out['floor_empty_call_us_p50'] = _floor_us()
    out['load_average_end'] = list(os.getloadavg())
    out['uptime_end'] = _uptime()
    out['definition'] = {
        'step_us_p50/p99': 'wall time of method.step per step [us] (median, 99th percentile)',
        'core_step_us_p50/p99': "wall time of the node core's step (CompensatorCore.step, "
                                'realtime, measurement of the previous step) [us]',
        'states': 'steps per method status (adapting/frozen/fixed/fallback) in the timed run',
        'scenario': 'closed loop on the method plant model (ARX, 2 um noise), BLWN 0-10 Hz '
                    f'5.08 mm target, first {WARMUP_S:g} s left out'}
    with open(os.path.join(out_dir, 'summary.json'), 'w', encoding='utf-8') as handle:
        json.dump(out, handle, indent=2)
    return out
