"""``rths bench site``: an unmodified OpenSeesPy model through ``rths site``, against rths itself.

The model is a 2-DOF shear building (:func:`two_dof_model`) under a ground
motion; its top floor carries the specimen.  Two runs of the same specimen:

* **site**: OpenSeesPy builds the building (zeroLength springs, as
  :mod:`rths_numerical.opensees_backend` does) plus a ``genericClient``
  element at the top floor whose server is ``rths site`` in its own process
  (config: the specimen behind the bridge and its compensator), and runs
  ``analyze(1, dt)`` step by step with CentralDifference;
* **direct**: the same building as rths's OpenSees numerical core, the same
  bridge and compensator in process, stepped lock-step by
  :func:`rths_common.replay.closed_loop`.

Reported (exactly these JSON fields): ``steps`` (analysis steps),
``round_trip_us_p50``/``_p99`` (wall time of one ``analyze(1, dt)`` of the
site run: every message of the step and OpenSees' own work; the site and the
client share one CPU and run SCHED_FIFO where allowed, as a lab's real-time
host would: on a loaded machine that is what keeps the p99 near the p50),
``max_abs_diff_vs_direct`` (top-floor displacement, site vs direct, over the
peak of the direct one), ``messages_per_step`` (client messages the site
handled per analysis step), ``safety_state_final`` (the site supervisor's
state when the client said goodbye; 0 = OK).

Specimens (``--specimen``): ``simulated`` (the repo's config: the 3-pole
actuator, shake table and DTM valve4 at 1024 Hz with its designed
compensator) or ``ideal`` (perfect actuator on a linear spring).  With
``ideal`` the bench also runs rths on both sides: the direct numerical core
with ``backend: genericclient`` (``--specimen tcp://``) against ``rths site``.

Ground motion: the 1940 El Centro record is not available offline (gmspy
has none; the Silva et al. benchmark's file may not be redistributed).  The
bench uses gmspy's Imperial Valley 1979 record at USGS station 5115 (an El
Centro array station) scaled by 0.10, the seed's El Centro factor.
"""

import contextlib
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import numpy as np

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

#: The fields of the JSON, in order (checked literally).
FIELDS = ('steps', 'round_trip_us_p50', 'round_trip_us_p99', 'max_abs_diff_vs_direct',
          'messages_per_step', 'safety_state_final')
RECORD, SCALE = 'imperial_valley', 0.10
FS_HZ = 1024.0
#: SCHED_FIFO priority of the site and of the client during the timed run (if allowed).
RT_PRIORITY = 80
#: Stiffness of the ideal specimen's spring [N/m] (a tenth of a storey's).
IDEAL_STIFFNESS_N_M = 1.6e5
#: The 2-DOF building: storey masses [kg], storey stiffnesses [N/m], modal damping.
STOREY_MASS_KG, STOREY_STIFFNESS_N_M, ZETA = 2000.0, 1.63e6, 0.02


def two_dof_model():
    """Return a 2-storey shear building (first mode ~2.8 Hz, the DTM's); top floor: interface."""
    from rths_numerical.model import model_from_dict
    m, k = STOREY_MASS_KG, STOREY_STIFFNESS_N_M
    return model_from_dict({
        'name': 'shear2', 'masses': [m, m], 'K': [[2 * k, -k], [-k, k]],
        'damping': {'type': 'modal', 'zeta': ZETA},
        'influence': [1.0, 1.0], 'interface_dofs': [1], 'output_dof': 1,
        'dof_names': ['floor1', 'floor2']}, 'bench site')


def ground_accel(steps: int, fs_hz: float = FS_HZ) -> np.ndarray:
    """Return the first ``steps`` samples at ``fs_hz`` of the record (module docstring) [m/s^2]."""
    from rths_numerical.ground_motion import ground_motion
    ag = ground_motion(RECORD, fs_hz, SCALE)
    if ag.size < steps:
        ag = np.concatenate([ag, np.zeros(steps - ag.size)])
    return ag[:steps]


def site_config(specimen: str, fs_hz: float = FS_HZ, n: int = 1, stiffness=None) -> dict:
    """Return the ``rths site`` config of a specimen: 'ideal' or 'simulated' (repo config)."""
    if specimen == 'ideal':
        k = [IDEAL_STIFFNESS_N_M] * n if stiffness is None else list(stiffness)
        return {'site': {'mode': 'pseudodynamic'},
                'bridge': {'backend': 'ideal', 'n_channels': n, 'stiffness_n_m': k,
                           'fs_hz': fs_hz},
                'compensator': {'scheme': 'identity', 'taps': [1.0], 'fs_hz': fs_hz}}
    if specimen == 'simulated':
        root = Path(os.environ.get('RTHS_ROOT', '.')) / 'config'
        return {'site': {'mode': 'pseudodynamic'}, 'bridge': str(root / 'bridge.yaml'),
                'compensator': str(root / 'compensator.yaml')}
    raise ValueError(f'--specimen {specimen!r}: use ideal or simulated')


class SiteProcess:
    """``rths site`` in its own process on a free port (OpenSeesPy holds the GIL)."""

    def __init__(self, config: dict, workdir, extra=()):
        """Write the config, start the site, wait until it listens."""
        import yaml
        self.dir = Path(workdir)
        self.dir.mkdir(parents=True, exist_ok=True)
        cfg = self.dir / 'site.yaml'
        cfg.write_text(yaml.safe_dump(config))
        self.bag, self.summary_path = self.dir / 'bag', self.dir / 'summary.json'
        cmd = [sys.executable, '-m', 'rths_bringup.cli', 'site', '--port', '0',
               '--config', str(cfg), '--bag', str(self.bag), '--summary',
               str(self.summary_path), '--wait-s', '120', *extra]
        self.proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
        self.lines = []
        self.port = None
        while self.port is None:
            line = self.proc.stderr.readline()
            if not line:
                raise OSError(f'rths site did not start: {"".join(self.lines)}')
            self.lines.append(line)
            if 'listening on ' in line:
                self.port = int(line.split('listening on ')[1].split()[0].rsplit(':', 1)[1])

    def finish(self, timeout: float = 120.0) -> dict:
        """Wait for the site to end; return its summary (exit code, steps, messages...)."""
        _, err = self.proc.communicate(timeout=timeout)
        self.lines.append(err)
        if not self.summary_path.is_file():
            raise OSError(f'rths site wrote no summary: {"".join(self.lines)}')
        return json.loads(self.summary_path.read_text())

    def log(self) -> str:
        """Everything the site printed."""
        return ''.join(self.lines)


@contextlib.contextmanager
def fifo(priority: int):
    """Run this process SCHED_FIFO at ``priority`` inside the block, if the system allows it."""
    try:
        before = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, ValueError):
        yield False
        return
    try:
        yield True
    finally:
        os.sched_setscheduler(0, before[0], before[1])


@contextlib.contextmanager
def pinned(cpu):
    """Pin this process (and its new children) to CPU ``cpu`` inside the block (None: all)."""
    if cpu is None:
        yield
        return
    before = os.sched_getaffinity(0)
    try:
        os.sched_setaffinity(0, {int(cpu)})
    except (OSError, ValueError) as err:
        raise ValueError(f'--cpu {cpu}: {err} (this machine has CPUs {sorted(before)})') \
            from None
    try:
        yield
    finally:
        os.sched_setaffinity(0, before)


def _apply_ground(ops, spec, model, ag, dt):
    """Apply the ground load of a linear model, as the OpenSees numerical core applies it."""
    ops.timeSeries('Path', 1, '-dt', dt, '-values', *ag.tolist(), 0.0)
    ops.pattern('Plain', 1, 1)
    loads = spec['transform'].T @ -(model.M @ model.gamma)
    for (node, _), value in zip(spec['dof_nodes'], loads, strict=True):
        if value:
            ops.load(node, float(value))


def run_client(model, ag, dt, port: int, host: str = '127.0.0.1') -> dict:
    """Run the OpenSeesPy model with a genericClient at the interface; per-step disp and time."""
    from rths_numerical.opensees_backend import import_opensees, linear_model_builder
    ops = import_opensees()
    ops.wipe()
    spec = linear_model_builder(model, model.interface_dofs)(ops)
    _apply_ground(ops, spec, model, ag, dt)
    args = []
    for node, dof in spec['interface']:
        args += ['-node', node, '-dof', dof] if len(spec['interface']) == 1 else []
    if len(spec['interface']) > 1:
        nodes = [node for node, _ in spec['interface']]
        args = ['-node', *nodes] + sum((['-dof', dof] for _, dof in spec['interface']), [])
    ops.element('genericClient', 10_000, *args, '-server', port, host)
    ops.constraints('Plain')
    ops.numberer('Plain')
    ops.system('FullGeneral')
    ops.algorithm('Linear', '-factorOnce')
    ops.integrator('CentralDifference')
    ops.analysis('Transient')
    n = ag.size
    disp = np.zeros((n, len(spec['interface'])))
    step_ns = np.zeros(n - 1, dtype=np.int64)
    for k in range(1, n):
        t0 = time.perf_counter_ns()
        if ops.analyze(1, dt) != 0:
            raise RuntimeError(f'OpenSees analyze failed at step {k}')
        step_ns[k - 1] = time.perf_counter_ns() - t0
        disp[k] = [ops.nodeDisp(node, dof) for node, dof in spec['interface']]
    ops.wipe()   # the genericClient says goodbye (die)
    return {'disp': disp, 'step_us': step_ns / 1e3}


def run_direct(model, ag, dt, bridge_params: dict, compensator_params: dict) -> dict:
    """Run the same building as rths's OpenSees core, bridge, compensator in process, lock-step."""
    from rths_actuator_bridge.bridge import Bridge
    from rths_common.replay import closed_loop
    from rths_compensator.core import CompensatorCore
    from rths_numerical.opensees_backend import OpenSeesSubstructure, linear_model_builder
    from rths_numerical.stepping import NumericalCore
    iface = list(model.interface_dofs)
    sub = OpenSeesSubstructure(linear_model_builder(model, iface), model, ag, dt,
                               'central_difference', iface, 1.0, 'relative', 0.0)
    lab = Bridge()
    lab.configure(bridge_params)
    lab.activate()
    try:
        out = closed_loop(NumericalCore(sub), CompensatorCore(dict(compensator_params)), lab,
                          sub.n_steps)
    finally:
        lab.close()
    return {'disp': out['interface_displacement'], 'safety_state': out['safety_state'],
            'force': out['force']}


def relative_diff(a, b) -> float:
    """Max |a - b| over max |b| (NaN anywhere: inf)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return float('inf')
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def tcp_specimen_diff(model, ag, dt, workdir) -> float:
    """Rths on both sides: the direct loop with ``backend: genericclient`` vs in process (ideal)."""
    import yaml

    from rths_actuator_bridge.site import load_site_config
    cfg_dir = Path(workdir)
    config = site_config('ideal')
    (cfg_dir / 'ideal.yaml').parent.mkdir(parents=True, exist_ok=True)
    (cfg_dir / 'ideal.yaml').write_text(yaml.safe_dump(config))
    params = load_site_config(cfg_dir / 'ideal.yaml')
    direct = run_direct(model, ag, dt, params['bridge'], params['compensator'])
    site = SiteProcess(config, cfg_dir / 'tcp')
    remote = dict(params['bridge'], backend='genericclient', site=f'tcp://127.0.0.1:{site.port}')
    remote.pop('stiffness_n_m')
    try:
        through = run_direct(model, ag, dt, remote, params['compensator'])
    finally:
        summary = site.finish()
    if summary['exit_code'] != 0:
        raise RuntimeError(f'rths site ended with {summary}: {site.log()}')
    return relative_diff(through['disp'][1:], direct['disp'][1:])


def bench_site(steps: int, specimen: str, workdir, progress=None, priority=RT_PRIORITY,
               cpu=None) -> tuple:
    """Run the bench; return ``(result with FIELDS, extra facts printed beside it)``."""
    import yaml

    from rths_actuator_bridge.site import load_site_config
    from rths_numerical.opensees_backend import OpenSeesSubstructure, linear_model_builder
    report = progress or (lambda done, total: None)
    workdir = Path(workdir)
    model, dt = two_dof_model(), 1.0 / FS_HZ
    ag = ground_accel(steps)
    config = site_config(specimen)
    workdir.mkdir(parents=True, exist_ok=True)
    (workdir / 'config.yaml').write_text(yaml.safe_dump(config))
    params = load_site_config(workdir / 'config.yaml')
    load_before = os.getloadavg()
    with pinned(cpu):   # the site inherits the CPU: client and site hand over on one core
        site = SiteProcess(config, workdir / 'site', ('--rt-priority', str(priority)))
        try:
            with fifo(priority):
                client = run_client(model, ag, dt, site.port)
        finally:
            summary = site.finish()
    report(1, 3)
    if summary['exit_code'] != 0:
        raise RuntimeError(f'rths site ended with {summary}: {site.log()}')
    # same-run floor: the building alone in OpenSees, no specimen, no network
    floor = OpenSeesSubstructure(linear_model_builder(model, [1]), model, ag, dt,
                                 'central_difference', [1], 1.0, 'relative', 0.0)
    floor_ns = np.zeros(steps - 1)
    for k in range(steps - 1):
        t0 = time.perf_counter_ns()
        floor.advance(np.zeros(1))
        floor_ns[k] = time.perf_counter_ns() - t0
    direct = run_direct(model, ag, dt, params['bridge'], params['compensator'])
    report(2, 3)
    analysis_steps = steps - 1
    result = {
        'steps': int(analysis_steps),
        'round_trip_us_p50': round(float(np.percentile(client['step_us'], 50)), 1),
        'round_trip_us_p99': round(float(np.percentile(client['step_us'], 99)), 1),
        'max_abs_diff_vs_direct': relative_diff(client['disp'][1:], direct['disp'][1:]),
        'messages_per_step': round(summary['messages'] / analysis_steps, 3),
        'safety_state_final': int(summary['safety_state']),
    }
    extra = {'specimen': specimen, 'cpu': cpu, 'rt_priority': priority,
             'record': f'{RECORD} x {SCALE} (USGS 5115)',
             'fs_hz': FS_HZ, 'site_loop_steps': summary['steps'],
             'floor_us_p50': round(float(np.percentile(floor_ns, 50)) / 1e3, 1),
             'peak_disp_m': float(np.max(np.abs(direct['disp'][1:]))),
             'loadavg_before': [round(x, 2) for x in load_before],
             'loadavg_after': [round(x, 2) for x in os.getloadavg()], 'bag': summary['bag']}
    if specimen == 'ideal':
        extra['tcp_specimen_max_abs_diff'] = tcp_specimen_diff(model, ag, dt,
                                                               workdir / 'both_sides')
    report(3, 3)
    return result, extra


def cmd_bench_site(args) -> int:
    """``rths bench site``."""
    from rths_common.files import atomic_open
    from rths_common.progress import Progress
    from rths_numerical.opensees_backend import opensees_available
    ok, why = opensees_available()
    if not ok:
        raise OSError(why)
    if args.steps < 2000:
        raise ValueError(f'--steps {args.steps}: the bench needs at least 2000 analysis steps')
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(args.keep) if args.keep else Path(tmp)
        with Progress(3, 'bench site', 'runs') as bar:
            result, extra = bench_site(args.steps + 1, args.specimen, workdir, bar.report,
                                       args.rt_priority, None if args.cpu < 0 else args.cpu)
    assert tuple(result) == FIELDS
    for key, value in {**result, **extra}.items():
        print(f'{key:28s} {value}')
    with atomic_open(args.out) as fh:
        json.dump(result, fh, indent=2)
    print(f'wrote {args.out}')
    return 0


def register(commands, benches):
    """Add ``rths bench site``."""
    p = benches.add_parser(
        'site', help='OpenSeesPy genericClient through rths site vs rths lock-step in process',
        description='Run an unmodified OpenSeesPy transient analysis (2-DOF shear building, '
                    'CentralDifference) whose genericClient element is served by rths site '
                    '(own process), and the same building and specimen through rths in process; '
                    'write steps, round_trip_us_p50, round_trip_us_p99, max_abs_diff_vs_direct, '
                    'messages_per_step and safety_state_final to --out. Needs OpenSeesPy (make '
                    'setup-opensees). Record: Imperial Valley 1979 (USGS 5115) x 0.10 (no 1940 '
                    'El Centro record is available offline).')
    p.add_argument('--out', required=True, help='JSON file to write')
    p.add_argument('--steps', type=int, default=8192,
                   help='analysis steps at 1024 Hz (default 8192 = 8 s; at least 2000)')
    p.add_argument('--specimen', choices=('simulated', 'ideal'), default='simulated',
                   help='simulated: the repo config (3-pole actuator + DTM valve4, designed '
                        'compensator; default); ideal: perfect actuator on a spring (also runs '
                        'rths on both sides through --specimen tcp://)')
    p.add_argument('--rt-priority', type=int, default=RT_PRIORITY, choices=range(0, 100),
                   metavar='0..99',
                   help=f'SCHED_FIFO priority of the site and of the client while timed '
                        f'(default {RT_PRIORITY}; 0 = normal scheduling)')
    p.add_argument('--cpu', type=int, default=max(os.sched_getaffinity(0)),
                   help='CPU the client and the site share while timed (default the last one; '
                        '-1 = no pinning): one core hands each message over without a '
                        'cross-CPU wake-up')
    p.add_argument('--keep', default=None, metavar='DIR',
                   help='keep the site configs, bags and summaries here')
    p.set_defaults(func=cmd_bench_site)
