"""The experimental site without sockets: a genericClient's trials through compensator and bridge.

:class:`SiteCore` answers the decoded messages of one client
(:mod:`.openfresco`); the server (:mod:`.site_server`) only moves bytes.  The
trial displacement is the interface displacement of the loop, the force
returned is the load cell's::

    trial disp x  ->  command = compensator.step(k, x)  ->  bridge.step(k, command)
                  ->  measured displacement, force  ->  getForce / getDaqResponse

Timing modes (``mode`` of :data:`SITE_PARAMS`):

``pseudodynamic``
    The client's trials step the loop; the client waits for each reading.
    The first trial is loop step 0 (OpenSees sends the structure at rest
    before its first analysis step).  Then, in each analysis step (up to its
    commitState), a trial whose displacement differs from the last one
    applied is one loop step (one sample of the plant, 1/fs_hz); a trial
    that repeats it moves nothing, and an analysis step that commits without
    any loop step makes one at its commit (the plant's time advances by one
    sample per analysis step).  OpenSees' explicit integrators
    (CentralDifference, NewmarkExplicit, ExplicitDifference) send one new
    displacement per analysis step, so one analysis step is one loop step;
    an implicit Newmark sends a predictor and a corrector (two loop steps).
``realtime``
    The site runs its own loop at fs_hz (:meth:`SiteCore.tick`, driven by the
    server's clock) from the first trial on; every trial replaces the target,
    each tick steps the loop with the latest target, and the client reads the
    latest measurement, as OpenFresco's real-time set-ups do.

Safety: every command passes the bridge's supervisor.  :meth:`SiteCore.safe_stop`
(a bad peer, a vanished client, a fault of the supervisor) trips it and steps
the loop without commands until it is STOPPED: brake, hold, ramp to the safe
position.  :class:`SiteRecorder` writes every loop step to the run's bag with
the loop topics of a normal run (interface displacement, command, measurement,
specimen channels, the bridge's status), so ``rths review`` reads it.
"""

from pathlib import Path
import threading
import time

import numpy as np
import yaml

from rths_common import cdr, topics
from rths_common.bagio import BagWriter
from rths_common.params import core_params
from rths_common.runinfo import flatten, load_params
from rths_compensator.core import CompensatorCore
from rths_compensator.params import (
    check_compensator_params,
    check_sampling_rate,
    load_compensator_params,
)

from . import openfresco as of
from . import safety

MODES = ('pseudodynamic', 'realtime')
#: The site's own parameters (section ``site`` of the config file): key -> (default, meaning).
SITE_PARAMS = {
    'mode': ('pseudodynamic', "'pseudodynamic' (each new trial displacement is one loop step; "
             "the client waits) or 'realtime' (the site's own loop at fs_hz; a trial replaces "
             'the target, the latest force is returned)'),
    'initial_stiffness_n_m': ([], '[N/m] n x n answer to getInitialStiff and getTangentStiff, '
                              'row by row (empty: zeros: the model supplies the stiffness)'),
    'damping_n_s_m': ([], '[N s/m] n x n answer to getDamp (empty: zeros)'),
    'mass_kg': ([], '[kg] n x n answer to getMass (empty: zeros)'),
    'client_timeout_s': (30.0, '[s] a connected client silent this long has vanished: safe '
                         'stop'),
    'allow': (['127.0.0.1', '::1'], 'client addresses or networks (CIDR, e.g. 10.0.0.0/24) '
              'allowed to connect; others are refused'),
}
#: Most steps :meth:`SiteCore.safe_stop` takes to reach STOPPED (far beyond hold + ramp).
MAX_STOP_STEPS = 10_000_000


class SiteStopped(Exception):
    """The supervisor left ACTIVE: the site is stopping (the text says why)."""


def site_params(raw: dict, where: str = 'site') -> dict:
    """Return the ``site`` section with defaults, unknown keys and bad values refused."""
    raw = dict(raw or {})
    unknown = sorted(set(raw) - set(SITE_PARAMS))
    if unknown:
        raise ValueError(f'{where}: unknown key(s) {", ".join(unknown)}; the site takes '
                         f'{", ".join(SITE_PARAMS)}')
    params = {key: raw.get(key, default) for key, (default, _) in SITE_PARAMS.items()}
    if params['mode'] not in MODES:
        raise ValueError(f"{where}: mode = {params['mode']!r}; use {' or '.join(MODES)}")
    timeout = params['client_timeout_s']
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) \
            or not 0 < timeout <= 86400:
        raise ValueError(f'{where}: client_timeout_s = {timeout!r} must be a number of seconds '
                         'in (0, 86400]')
    allow = params['allow']
    if isinstance(allow, str):
        allow = [allow]
    if not isinstance(allow, list) or not all(isinstance(a, str) for a in allow):
        raise ValueError(f'{where}: allow must be a list of addresses or networks, e.g. '
                         '[127.0.0.1, 10.0.0.0/24]')
    params['allow'] = allow
    return params


def site_matrix(value, n: int, key: str) -> np.ndarray:
    """Return the n x n matrix of a ``site`` key (empty: zeros; ValueError names the fix)."""
    m = np.asarray(value if value is not None else [], dtype=float).ravel()
    if m.size == 0:
        return np.zeros((n, n))
    if m.size != n * n or not np.all(np.isfinite(m)):
        raise ValueError(f'site: {key} has {m.size} value(s); give {n * n} finite values (an '
                         f'{n} x {n} matrix row by row for the {n} interface DOF(s)) or none')
    return m.reshape(n, n)


class SiteRecorder:
    """The run's bag: every loop step of the site as the loop topics of a normal run."""

    def __init__(self, path, run_info: dict):
        """Create the bag at ``path`` (must not exist) with the run information."""
        self.writer = BagWriter(path, run_info=run_info)
        self.path = Path(path)

    def step(self, k: int, x, command, result, compute_us: float):
        """Write loop step ``k``: target ``x``, ``command`` and the bridge's ``result``."""
        w, stamp = self.writer, time.time_ns()
        if x is not None:
            w.write(topics.INTERFACE_DISPLACEMENT, stamp, cdr.pack_step_arrays(stamp, k, x))
        if command is not None:
            w.write(topics.COMMAND, stamp, cdr.pack_step_arrays(stamp, k, command))
        w.write(topics.MEASUREMENT, stamp, cdr.pack_step_arrays(
            stamp, k, result.applied, result.displacement, result.force))
        ch = result.channels
        if 'rel_disp' in ch:
            w.write(topics.SPECIMEN, stamp, cdr.pack_step_arrays(
                stamp, k, (ch.get('table_accel', np.nan),), (ch['rel_disp'],),
                (ch.get('rel_vel', np.nan),)))
        w.write(topics.STATUS, stamp, cdr.pack_status(
            stamp, 'bridge', k, compute_us=compute_us, safety_state=result.state,
            fault=result.fault))

    def event(self, text: str):
        """Write what happened to the session (a bad peer, its end) to the status topic."""
        stamp = time.time_ns()
        self.writer.write(topics.STATUS, stamp, cdr.pack_status(stamp, 'site', 0, fault=text))

    def close(self):
        """Finish the bag (readable from here on)."""
        self.writer.close()


class SiteCore:
    """One client's session on the site: the protocol's actions on compensator and bridge.

    ``bridge``: a configured :class:`~.bridge.Bridge` (activated by :meth:`accept`);
    ``compensator``: a :class:`rths_compensator.core.CompensatorCore`; ``params``:
    :func:`site_params`; ``recorder``: a :class:`SiteRecorder` or None.
    """

    def __init__(self, bridge, compensator, params: dict, recorder=None, log=print):
        """Check the site against the bridge (mode, matrices) before any client comes."""
        self.bridge, self.comp, self.params = bridge, compensator, params
        self.recorder, self.log = recorder, log
        self.n = bridge.backend.n_channels
        self.fs_hz = float(bridge.backend.limits.fs_hz)
        self.realtime = params['mode'] == 'realtime'
        if not self.realtime and bridge.delay_steps:
            raise ValueError(f'bridge: command_delay_steps = {bridge.delay_steps}: a '
                             'pseudo-dynamic site answers each trial with its own measurement; '
                             'set it to 0 (or use mode realtime)')
        stiff = site_matrix(params['initial_stiffness_n_m'], self.n, 'initial_stiffness_n_m')
        self.matrices = {of.GET_INITIAL_STIFF: stiff, of.GET_TANGENT_STIFF: stiff,
                         of.GET_DAMP: site_matrix(params['damping_n_s_m'], self.n,
                                                  'damping_n_s_m'),
                         of.GET_MASS: site_matrix(params['mass_kg'], self.n, 'mass_kg')}
        self.sizes = None
        self.k = 0                    # the next loop step
        self.latest = None            # the bridge's StepResult of the latest step
        self.applied_trial = None     # pseudo-dynamic: the displacement of the latest step
        self.stepped = False          # pseudo-dynamic: a step in this analysis step
        self.target = None            # realtime: the latest trial displacement
        self.trial_time = float('nan')
        self.commits = 0
        self.lock = threading.Lock()  # realtime: the clock thread and the client thread
        self.stopped = ''             # why the site stopped ('' while it runs)
        self.messages = 0             # client messages handled
        self.final_state = None       # the supervisor's state when the session ended
        self._prev = np.zeros((2, self.n))   # measured displacements of the last two steps

    # ------------------------------------------------------------------ session
    def accept(self, sizes: of.Sizes):
        """Take the client's set-up: refuse a size mismatch before anything moves, then arm."""
        sizes.check_interface(self.n)
        self.sizes = sizes
        self.bridge.activate()
        self._zero = of.encode_reply(sizes, ())

    def handle(self, request: of.Request):
        """Carry out one client message; return the reply bytes, or None (no reply)."""
        self.messages += 1
        action = request.action
        if action == of.SET_TRIAL_RESPONSE:
            self.trial_time = request.time
            if self.realtime:
                with self.lock:
                    self.target = request.disp
            elif self.applied_trial is None \
                    or not np.array_equal(request.disp, self.applied_trial):
                self._step(request.disp)
            return None
        if action == of.COMMIT_STATE:
            self.commits += 1
            if not self.realtime:
                if self.applied_trial is not None and not self.stepped:
                    self._step(self.applied_trial)
                self.stepped = False
            return None
        if action in of.MATRICES:
            return of.encode_matrix(self.sizes, self.matrices[action])
        if action in of.ENDS:
            return None
        return of.encode_reply(self.sizes, self._reading(action))

    def _reading(self, action: int) -> np.ndarray:
        """Return a get-action's values from the latest measurement (zeros before the first)."""
        with self.lock:
            latest, prev = self.latest, self._prev.copy()
        if latest is None:
            disp = force = vel = acc = np.zeros(self.n)
            t = 0.0
        else:
            disp, force = latest.displacement, latest.force
            vel = (disp - prev[0]) * self.fs_hz
            acc = (disp - 2 * prev[0] + prev[1]) * self.fs_hz ** 2
            t = (latest.step + 1) / self.fs_hz
        if action == of.GET_DAQ_RESPONSE:
            return of.daq_values(self.sizes, disp, vel, acc, force, t)
        return {of.GET_DISP: disp, of.GET_VEL: vel, of.GET_ACCEL: acc, of.GET_FORCE: force,
                of.GET_TIME: np.array([t])}[action]

    # ------------------------------------------------------------------ loop steps
    def _step(self, x):
        """One loop step with target ``x`` (None: no new command); SiteStopped on a fault."""
        started = time.perf_counter_ns()
        k = self.k
        command = None
        if x is not None:
            result = self.comp.step(k, x)
            if result is not None:
                command = result.output
                self.bridge.receive(k, command)
        measured = self.bridge.step(k, self.bridge.due(k))
        if self.comp.adaptive:
            self.comp.measure(k, measured.displacement, measured.applied)
        with self.lock:
            if self.latest is not None:
                self._prev[1] = self._prev[0]
                self._prev[0] = self.latest.displacement
            self.latest = measured
        self.k = k + 1
        if x is not None:
            self.applied_trial = x
            self.stepped = k > 0      # step 0 (the structure at rest) precedes analysis step 1
        if self.recorder is not None:
            self.recorder.step(k, x, command, measured,
                               (time.perf_counter_ns() - started) / 1e3)
        if measured.state != safety.ACTIVE and not self.stopped:
            self.stopped = measured.fault or 'the supervisor left ACTIVE'
            raise SiteStopped(f'safety supervisor at step {k}: {self.stopped}')

    def tick(self):
        """Realtime: one step of the site's own loop with the latest target (SiteStopped)."""
        with self.lock:
            x = self.target
        self._step(x)

    def started(self) -> bool:
        """Realtime: True once a trial has arrived (the clock starts then)."""
        return self.target is not None

    def safe_stop(self, reason: str) -> int:
        """Trip the supervisor (if it still runs) and step until STOPPED; return the steps."""
        bridge = self.bridge
        if not self.stopped:
            self.stopped = reason
        if bridge.state == safety.INACTIVE or bridge.backend.lifecycle != 'active':
            bridge.supervisor.emergency_stop(reason)
            return 0
        if bridge.state == safety.ACTIVE:
            bridge.emergency_stop(reason)
        steps = 0
        while bridge.state != safety.STOPPED and steps < MAX_STOP_STEPS:
            try:
                self._step(None)
            except SiteStopped:
                pass
            steps += 1
        return steps

    def finish(self):
        """End the session after the goodbye: deactivate the bridge (the actuator holds)."""
        self.final_state = self.bridge.state
        self.bridge.deactivate()

    def summary(self) -> dict:
        """Return steps, commits, messages, the supervisor's state at the end and fault."""
        sup = self.bridge.supervisor
        state = sup.state if self.final_state is None else self.final_state
        return {'steps': self.k, 'commits': self.commits, 'messages': self.messages,
                'safety_state': int(state), 'fault': sup.fault, 'stopped': self.stopped}


# ---------------------------------------------------------------------- configuration
def _section(doc: dict, name: str, node: str, base: Path, default: Path) -> dict:
    """Return a node's parameters: a params file (relative to the config), inline, default."""
    value = doc.get(name, str(default))
    if isinstance(value, dict):
        return dict(value.get('ros__parameters', value))
    if not isinstance(value, str):
        raise ValueError(f'site config: {name} must be a params file path or a mapping of '
                         'parameters')
    path = Path(value) if Path(value).is_absolute() else base / value
    if node == 'compensator':
        return load_compensator_params(path)
    return load_params(path, node)


def load_site_config(path=None, config_dir=None) -> dict:
    """Return ``{'site', 'bridge', 'compensator'}`` parameters of a site config file, checked.

    The file (YAML) holds ``site:`` (:data:`SITE_PARAMS`), and ``bridge:`` and
    ``compensator:``, each a params file path (relative to the file) or the
    parameters inline; missing ones are ``config_dir``'s bridge.yaml and
    compensator.yaml.  Without a file: those two and the site defaults.
    """
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from .bridge import check_core_params
    config_dir = (Path(config_dir) if config_dir else Path('config')).resolve()
    doc, base = {}, config_dir
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise OSError(f'site config {path} not found')
        try:
            doc = yaml.safe_load(path.read_text()) or {}
        except yaml.YAMLError as err:
            raise ValueError(f'{path}: not valid YAML ({err})') from None
        if not isinstance(doc, dict) or set(doc) - {'site', 'bridge', 'compensator'}:
            raise ValueError(f'{path}: expected the keys site, bridge, compensator at the top '
                             f'(got {sorted(doc) if isinstance(doc, dict) else type(doc)})')
        base = path.parent
    site = site_params(doc.get('site'), f'{path or "site"}: site')
    bridge = core_params(_section(doc, 'bridge', 'bridge', base, config_dir / 'bridge.yaml'))
    bridge = {k: v for k, v in bridge.items()
              if k not in ('use_sim_time', 'start_type_description_service')
              and not k.startswith('qos_overrides')}
    check_core_params(bridge)
    compensator = core_params(_section(doc, 'compensator', 'compensator', base,
                                       config_dir / 'compensator.yaml'))
    compensator.setdefault('denominator', [1.0])
    check_compensator_params(compensator, 'site config: compensator')
    fs = float(bridge.get('fs_hz', safety.SAFETY_PARAMS['fs_hz'][0]))
    if 'fs_hz' in compensator:
        check_sampling_rate(compensator, fs, 'site config: compensator', "the bridge's fs_hz")
    return {'site': site, 'bridge': bridge, 'compensator': compensator}


def run_info(config: dict) -> dict:
    """Return the bag's run information of a site run (kind ``rths``, no numerical section)."""
    fs = float(config['bridge'].get('fs_hz', safety.SAFETY_PARAMS['fs_hz'][0]))
    info = flatten('rths', fs, config['site']['mode'],
                   {'bridge': config['bridge'], 'compensator': config['compensator'],
                    'site': config['site']})
    return info


def build_site(config: dict, bag=None, log=print) -> 'SiteCore':
    """Create the bridge (configured, not yet active), compensator, recorder and site core."""
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from .bridge import Bridge
    bridge = Bridge()
    bridge.configure(config['bridge'])
    try:
        core = SiteCore(bridge, CompensatorCore(dict(config['compensator'])), config['site'],
                        None, log)
        if bag:
            core.recorder = SiteRecorder(bag, run_info(config))
        return core
    except Exception:
        bridge.close()
        raise
