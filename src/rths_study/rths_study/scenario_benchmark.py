"""The RTHS benchmark (Silva et al. 2020) as study scenarios: ``benchmark`` and ``design``.

``benchmark``: one run is one virtual RTHS of the benchmark
(:mod:`rths_bench.rths_benchmark`): a partitioning case, a control plant whose Table 2
parameters the study may vary (the perturbed plants of the paper's section 4.3 are
``random`` draws of b1, b2, a3, k_e), a controller (the paper's ``example`` PI + lead,
the project's ``fir``, or an adaptive method started from it) and a ground-motion
record.  Metrics: the benchmark's J1-J9 and ``unstable``.  A chunk of runs advances in
one vectorised loop (:func:`rths_bench.rths_benchmark.run_batch`); each run draws its
sensor noise from its own seed, so its numbers do not depend on its chunk.  The FIR
design (identification of the nominal plant, then design) is made once per worker
process for each set of design options, and is the same on every worker (fixed seeds).

``design``: one run is the lab procedure of the benchmark's ``fir`` controller (BLWN
test, ARX grid, FIR design, verification on the plant) with the design options the
study varies; metrics are the verification tracking error and the design's predicted
0-20 Hz delay and gain error.

Records: ``elcentro``, ``kobe``, ``morganhill`` (the benchmark's files, not
redistributable: ``$RTHS_DATA_DIR`` or the ``data_dir`` setting),
``gmspy:imperial_valley``, ``gmspy:kobe``, ``gmspy:northridge`` (the seed's public
records, installed with the project) or a file path.
"""

import functools
import math

import numpy as np

from rths_actuator_bridge.silva2020 import FS_HZ, Silva2020Params
from rths_bench.rths_benchmark import BENCHMARK_SCHEME
from rths_compensator.methods import adaptive_names
from rths_compensator.schemes import fir_schemes
from rths_numerical.ground_motion import RECORDS as SEED_RECORDS

from .scenarios import Scenario
from .setting import Setting

#: Control-plant parameters a study may vary (Table 2 of the benchmark, SI units).
PLANT_PARAMETERS = ('gain', 'a1b0', 'a2', 'b1', 'b2', 'a3', 'm_e', 'k_e', 'zeta_e')
#: Options of the FIR design (:func:`rths_bench.rths_benchmark.identify_and_design`).
DESIGN = {'taps': Setting(int, 200, minimum=2, maximum=4096, doc='FIR taps n'),
          'fc_hz': Setting(float, 30.0, minimum=0.1, maximum=2000.0,
                           doc='passband edge of the FIR design [Hz]'),
          'scheme': Setting(str, BENCHMARK_SCHEME, choices=fir_schemes(),
                            doc='FIR design scheme'),
          'epsilon': Setting(float, 0.002, minimum=0.0, doc='passband tolerance'),
          'lowpass_hz': Setting(float, 400.0, minimum=1.0, maximum=2000.0,
                                doc='cut-off of the order-4 target low-pass [Hz]')}
J_METRICS = {f'J{i}': 'float' for i in range(1, 10)}


def _design_options(values: dict) -> dict:
    return {'n_taps': values['taps'], 'fc_hz': values['fc_hz'], 'scheme': values['scheme'],
            'epsilon': values['epsilon'], 'lowpass_hz': values['lowpass_hz']}


@functools.lru_cache(maxsize=8)
def _designed(options: tuple):
    """``(design, info)`` of the benchmark's FIR for these options (once per process)."""
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_bench.rths_benchmark import identify_and_design
    return identify_and_design(log=lambda msg: None, **dict(options))


@functools.lru_cache(maxsize=8)
def _ground(record: str, scale, duration_s, data_dir):
    """Scaled record at the benchmark's 4096 Hz (read once per process)."""
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_bench.rths_benchmark import ground_acceleration
    _, ag = ground_acceleration(record, FS_HZ, scale, data_dir, duration_s or None)
    return ag


@functools.lru_cache(maxsize=16)
def _reference(case: str, record: str, scale, duration_s, data_dir):
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_bench.rths_benchmark import reference_response
    return reference_response(case, _ground(record, scale, duration_s, data_dir), 1.0 / FS_HZ)


def check_records(records, data_dir):
    """Refuse a record that cannot be read, naming ``records[i]`` and the fix."""
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_bench.rths_benchmark import GMSPY_PREFIX, record_path
    for i, record in enumerate(records):
        try:
            if record.startswith(GMSPY_PREFIX):
                if record[len(GMSPY_PREFIX):] not in SEED_RECORDS:
                    raise ValueError(f'use {GMSPY_PREFIX} with one of {", ".join(SEED_RECORDS)}')
            else:
                record_path(record, data_dir)
        except (OSError, ValueError) as err:
            raise ValueError(f'records[{i}]: {err}') from None


class BenchmarkScenario(Scenario):
    """Virtual RTHS of the benchmark: J1-J9 of a controller on a (perturbed) plant."""

    kind = 'benchmark'
    summary = 'the RTHS benchmark (Silva et al. 2020): J1-J9 per plant, controller, record'
    settings = {'case': Setting(str, '1', choices=('1', '2', '3', '4'),
                                doc='partitioning case of the benchmark'),
                'duration_s': Setting(float, 0.0, minimum=0.0,
                                      doc='seconds of record (0: all of it)'),
                'scale': Setting(float, None, minimum=0.0,
                                 doc="record scale (default: the benchmark's 0.4 for its "
                                     'records, 1 for others)'),
                'data_dir': Setting(str, None, doc='directory of the benchmark records '
                                                   '(default $RTHS_DATA_DIR)'),
                **DESIGN}
    # a3 unbounded: the paper's normal draws (3.3 +- 1.3) give a3 < 0 about once in 200
    parameters = {**{name: Setting(float, minimum=None if name == 'a3' else 0.0)
                     for name in PLANT_PARAMETERS}, **DESIGN}
    controllers = ('example', 'fir') + adaptive_names()
    default_controllers = ('example',)
    uses_records = True
    default_records = ('elcentro',)
    metrics = {**J_METRICS, 'unstable': 'bool'}
    chunk = 25

    def check(self, spec):
        """Refuse a record that cannot be read, before anything starts."""
        check_records(spec.records, spec.settings['data_dir'])

    def evaluate(self, settings, runs):
        """Run the chunk in one batch per design (runs of a chunk share record, controller)."""
        groups = {}
        for i, run in enumerate(runs):
            values = {k: run['params'].get(k, settings[k]) for k in DESIGN}
            groups.setdefault(tuple(sorted(_design_options(values).items())), []).append(i)
        out = [None] * len(runs)
        for options, idx in groups.items():
            for i, metrics in zip(idx, self._batch(settings, [runs[i] for i in idx], options),
                                  strict=True):
                out[i] = metrics
        return out

    def _batch(self, settings, runs, options):
        # lazy: start-up cost: SciPy (~1 s), which this module needs only here
        from rths_bench import rths_benchmark as rb
        dt = 1.0 / FS_HZ
        record, controller = runs[0]['record'], runs[0]['controller']
        where = (record, settings['scale'], settings['duration_s'], settings['data_dir'])
        ag = _ground(*where)
        ref = _reference(settings['case'], *where)
        plants = [Silva2020Params(**{k: v for k, v in run['params'].items()
                                     if k in PLANT_PARAMETERS}) for run in runs]
        designed = None if controller == 'example' else _designed(options)
        ctrl = rb.make_controller(controller, len(runs), dt, dict(options), designed=designed)
        out = rb.run_batch([(settings['case'], p) for p in plants], ag, ctrl,
                           seeds=[run['seed'] for run in runs])
        return [_metrics(out['x_m'][i], out['y_n'][i], ref, dt) for i in range(len(runs))]


def _metrics(x_m, y_n, ref, dt) -> dict:
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_bench import rths_benchmark as rb
    bad = rb.unstable(x_m, ref)
    if not (np.all(np.isfinite(x_m)) and np.all(np.isfinite(y_n))):
        return {**{name: math.nan for name in J_METRICS}, 'unstable': True}
    with np.errstate(all='ignore'):
        js = rb.criteria(x_m, y_n, ref, dt)
    return {**{k: float(v) for k, v in js.items()}, 'unstable': bad}


class DesignScenario(Scenario):
    """The benchmark's FIR lab procedure with the design options a study varies."""

    kind = 'design'
    summary = "the benchmark's FIR identification and design: verification error, delay"
    settings = dict(DESIGN)
    parameters = {**DESIGN, 'identification_seed': Setting(int, 7, minimum=0)}
    metrics = {'verification_error_pct': 'float', 'delay_ms': 'float',
               'gain_error_db': 'float', 'highpass_gain_db': 'float', 'arx_na': 'float',
               'arx_d': 'float'}
    chunk = 1

    def evaluate(self, settings, runs):
        """Identify and design for each run (about 2 s each)."""
        # lazy: start-up cost: SciPy (~1 s), which this module needs only here
        from rths_bench.rths_benchmark import identify_and_design
        out = []
        for run in runs:
            values = {k: run['params'].get(k, settings[k]) for k in DESIGN}
            seed = run['params'].get('identification_seed', 7)
            _, info = identify_and_design(seed=seed, log=lambda msg: None,
                                          **_design_options(values))
            pred = info['predicted_0_20hz']
            out.append({'verification_error_pct': info['verification_error_pct'],
                        'delay_ms': pred.get('delay_ms', math.nan),
                        'gain_error_db': pred.get('gain_error_db', math.nan),
                        'highpass_gain_db': pred.get('highpass_gain_db', math.nan),
                        'arx_na': float(info['arx']['na']), 'arx_d': float(info['arx']['d'])})
        return out
