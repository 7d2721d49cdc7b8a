"""Actuator-bridge node: the ROS shell of :class:`rths_actuator_bridge.bridge.Bridge`.

``ros2 run rths_actuator_bridge bridge_node --ros-args --params-file config/bridge.yaml``

Subscribes ``/rths/command``, steps the backend (simulated plant or UDP servo
controller) under the safety supervisor, and publishes ``/rths/measurement`` and
``/rths/status``; lifecycle services, command source, emergency stop and the
realtime clocks (behaviour and measurements: docs/nodes.md).
"""

import functools
import sys
import time

from lifecycle_msgs.msg import State
import numpy as np
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import TransitionCallbackReturn
from std_msgs.msg import String, UInt64

from rths_actuator_bridge.backend import Backend
from rths_actuator_bridge.managed import ManagedNode
from rths_actuator_bridge.safety import HOLD, RAMP, STOPPED, SafetyLimits
from rths_common import lifeline, topics
from rths_common import node_support as ns
from rths_common.qos import loop_qos, loop_writer_qos, run_info_qos, status_qos
from rths_common.stepping import Driver, TickClock
from rths_common.transport import Transport
from rths_msgs.msg import Command, ControllerStatus, LoopStatus, Measurement, Specimen
from rths_msgs.srv import EmergencyStop

NODE_PARAMS = {'mode': 'lockstep', 'executor': 'events', 'autostart': True,
               'wait_for_subscribers': 1,
               'watchdog_timeout_s': 5.0, 'clock': 'loop', 'spin_margin_us': 0.0,
               'direct_delivery': True,
               'timing_out': '', 'publish_specimen': 'auto',
               'command_source': 'compensator',
               **ns.TUNING_PARAMS, **ns.RUN_PARAMS}
CLOCKS = ('loop', 'thread', 'timer')
EXIT_SAFETY_STOP = 3
#: Shortest time between two graph scans for the command source's writer gids [s].
RESCAN_S = 0.05


def check_bridge_params(params: dict) -> dict:
    """Validate the bridge's flat parameters; return those of the core (backend + safety).

    Unknown keys (typos), non-finite or out-of-unit limits raise ValueError
    naming the field and the fix.  Used by the node and by ``rths launch``'s
    pre-flight check (:mod:`rths_bringup.preflight`).
    """
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_actuator_bridge.bridge import check_core_params

    core = {k: v for k, v in params.items()
            if k not in NODE_PARAMS and k not in ns.ROS_BUILTIN_PARAMS
            and not k.startswith('qos_overrides')}
    return check_core_params(core, NODE_PARAMS)


class BridgeNode:
    """ROS shell around a backend and its safety supervisor."""

    def __init__(self):
        # lazy: start-up cost: SciPy (~1 s), which this module needs only here
        from rths_actuator_bridge.bridge import Bridge, backend_class, param_schema

        managed = functools.partial(ManagedNode, shell=self)   # UNCONFIGURED
        self.node = ns.make_node('bridge', param_schema(NODE_PARAMS), NODE_PARAMS, managed)
        params = ns.parameters(self.node)
        self.own = {k: ns.param(params, k, v) for k, v in NODE_PARAMS.items()}
        self.params = params = check_bridge_params(params)
        self.log = ns.StepLogger(self.node.get_logger())
        self.lockstep = self.own['mode'] == 'lockstep'
        if self.own['mode'] not in ('lockstep', 'realtime'):
            raise ValueError(f"bridge node: mode {self.own['mode']!r}: use lockstep or realtime")
        if self.own['clock'] not in CLOCKS:
            raise ValueError(f"bridge node: clock {self.own['clock']!r}: use one of {CLOCKS}")
        self.bridge = Bridge()                        # configured by on_configure
        limits = SafetyLimits.from_params(params)
        self.fs_hz = limits.fs_hz
        self.launcher_loss_stop_s = limits.launcher_loss_stop_s
        self.launcher_lost = False
        self.finalized = False
        qos = loop_qos(self.own['mode'])
        self.pub = self.node.create_publisher(Measurement, topics.MEASUREMENT,
                                              loop_writer_qos(self.own['mode']))
        self.status_pub = self.node.create_publisher(LoopStatus, topics.STATUS, status_qos())
        # Table/DTM sensor channels for the review and the discrepancy workflow (off the loop path;
        # in realtime only when asked for, each publish costs tens of microseconds).
        self.specimen_pub = None
        publish = self.own['publish_specimen']  # 'auto': in lock-step only
        if publish is True or publish == 'true' or (publish == 'auto' and self.lockstep):
            self.specimen_pub = self.node.create_publisher(Specimen, topics.SPECIMEN, status_qos())
        # Counts of an external controller's replies, for the bag and the review.
        self.controller_pub = None
        self.controller_seen = (-1, -1)   # (backend revision, step) last published
        if backend_class(params).counts is not Backend.counts:   # it counts its replies
            self.controller_pub = self.node.create_publisher(ControllerStatus, topics.CONTROLLER,
                                                             status_qos())
        ns.wait_for_readers(self.node, self.pub, self.own['wait_for_subscribers'])
        raw = not self.lockstep   # lean messages: CDR bytes in and out (rths_common.cdr)
        run_id = self.own['run_id']
        self.io_in = Transport(Command, ('command',), raw, run_id)
        self.io_out = Transport(Measurement, ('applied', 'displacement', 'force'), raw, run_id)
        self.node.create_subscription(String, topics.EMERGENCY_STOP, self.on_estop_topic, 10)
        self.node.create_service(EmergencyStop, topics.EMERGENCY_STOP_SERVICE, self.on_estop_srv)
        # Command source guard: only the configured node's writer may command the actuator.
        self.source_gids = set()       # writer gids of the command_source node on /rths/command
        self.foreign = {}              # gid -> 'namespace/node' of other publishers (logged once)
        self.foreign_rejected = 0
        self.last_scan = float('-inf')  # monotonic time of the last scan for the source's gids
        self.clock = ns.StepClock()
        self.step = -1                 # last step written to the backend
        # lock-step: a command's arrival is its tick; realtime: the clock hands k to the bridge
        self.driver = Driver(self.bridge, True, self.on_reject, step=self.tick_now)
        self.ticks = None if self.lockstep else TickClock(self.fs_hz)
        self.last_command_t = None
        self.stopped = False
        self.fault_logged = False
        self.stop_timer = None
        self.node.create_timer(0.1, self.watchdog)
        self.n_steps = None            # steps of the run (from the numerical node)
        self.late = 0                  # commands that arrived after their tick
        self.run_over = False
        self.clock_timer = None
        # the container's direct delivery: True while no loop message crosses DDS (spin_clocked)
        self.quiet = None
        # tick_cpu_ns: the CPU time of the thread that ticks (composed: every node's callbacks
        # run on it), so a stall can be told apart: worked through (on CPU) or waited
        self.timing = {'tick_step': [], 'tick_wall_ns': [], 'tick_late_ns': [], 'missed': [],
                       'tick_cpu_ns': [],
                       'recv_step': [], 'recv_wall_ns': [], 'recv_stamp_ns': []}
        self.cpu_loop = None
        if self.ticks is not None:
            self.node.create_subscription(UInt64, topics.RUN_STEPS, self.on_run_steps,
                                          run_info_qos())
            self.tuning = ns.tune_process(*ns.tuning(self.own, 'bridge'))
            self.log.info(f"{self.own['mode']}: bridge is the clock at {self.fs_hz:g} Hz "
                          f"(clock {self.own['clock']}, executor {self.own['executor']}); "
                          f'{self.tuning}')
        self.config_error = None       # why configure/activate failed, for autostart
        if self.own['autostart']:      # configure and activate now, as `ros2 lifecycle set` would
            for trigger in (self.node.trigger_configure, self.node.trigger_activate):
                if trigger() != TransitionCallbackReturn.SUCCESS:
                    raise self.config_error or RuntimeError(f'bridge: {trigger.__name__} failed')
        # Last: the compensator arms once this reader is seen (and the run starts after it),
        # so tuning, configure and activate are done before the first command can arrive
        # (realtime: a command arriving meanwhile waited ~80 ms and started a late clock).
        self.node.create_subscription(Command, topics.COMMAND, self.on_command, qos, raw=raw)

    # ---------------------------------------------------------------- lifecycle
    def on_configure(self, _state) -> TransitionCallbackReturn:
        """UNCONFIGURED -> INACTIVE: the backend and the supervisor from the parameters."""
        try:
            self.bridge.configure(self.params)        # INACTIVE: nothing moves
        except Exception as err:   # kept for autostart and logged (rclpy would drop it)
            self.config_error = err
            self.log.error(f'configure failed: {err}')
            return TransitionCallbackReturn.FAILURE
        backend = self.bridge.backend
        self.log.info(f'bridge configured: backend {self.params.get("backend", "simulated")}, '
                      f'{backend.n_channels} channel(s), stroke +-{backend.limits.stroke_m} m'
                      + (f', rig file {self.bridge.rig.where.removeprefix("rig file ")}: '
                         f'actuators {", ".join(self.bridge.rig.actuators)}'
                         if self.bridge.rig else ''))
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, _state) -> TransitionCallbackReturn:
        """INACTIVE -> ACTIVE: from now on commands may move the actuator (not after a stop)."""
        if self.stopped:
            self.log.warning('activate refused: the bridge stopped safely in this run; start a '
                             'new bridge node for a new run')
            return TransitionCallbackReturn.FAILURE
        try:
            self.bridge.activate()
        except Exception as err:   # kept for autostart and logged (rclpy would drop it)
            self.config_error = err
            self.log.error(f'activate failed: {err}')
            return TransitionCallbackReturn.FAILURE
        self.log.info('bridge active')
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, _state) -> TransitionCallbackReturn:
        """ACTIVE -> INACTIVE: once a command has moved the actuator, through the safe stop."""
        if self.stopped:
            return TransitionCallbackReturn.SUCCESS   # the safety stop deactivated the backend
        if self.step >= 0:
            self.start_safe_stop('deactivate requested')   # hold, ramp, stop: then inactive
        else:
            self.bridge.deactivate()
            self.log.info('bridge inactive')
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, _state) -> TransitionCallbackReturn:
        """INACTIVE -> UNCONFIGURED: release the backend; refused once the actuator has moved."""
        if self.step >= 0:
            self.log.warning('cleanup refused: commands have moved the actuator in this run; '
                             'shut the node down and start a new one')
            return TransitionCallbackReturn.FAILURE
        self.bridge.cleanup()
        self.log.info('bridge unconfigured: backend released')
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, _state) -> TransitionCallbackReturn:
        """-> FINALIZED: a moved actuator stops safely first (exit 3); the spin then ends."""
        if self.step >= 0 and not self.stopped:
            self.start_safe_stop('shutdown requested')
        else:
            self.bridge.cleanup()
            self.finalized = True
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, _state) -> TransitionCallbackReturn:
        """Handle a transition that raised: safe stop if the actuator moved, else unconfigure."""
        self.log.error('lifecycle transition failed with an exception')
        if self.step >= 0 and not self.stopped:
            self.start_safe_stop('lifecycle error')
            return TransitionCallbackReturn.FAILURE
        self.bridge.cleanup()
        return TransitionCallbackReturn.SUCCESS

    def settle_inactive(self):
        """After a safety stop the backend is inactive: so is the managed node."""
        if self.node.state().id == State.PRIMARY_STATE_ACTIVE:
            self.node.trigger_deactivate()

    # ---------------------------------------------------------------- loop
    def scan_command_publishers(self):
        """Refresh the command source's writer gids; log every foreign publisher once."""
        source = self.own['command_source']
        gids = set()
        for info in self.node.get_publishers_info_by_topic(topics.COMMAND):
            gid = ns.gid_text(info.endpoint_gid)
            if info.node_name.startswith('_NODE_NAME_UNKNOWN'):
                # the graph shows the writer before its node's name (rmw discovery info comes
                # later): neither source nor named foreign yet; its messages are refused
                continue
            if info.node_name == source:
                gids.add(gid)
            elif gid not in self.foreign:
                name = f'{info.node_namespace.rstrip("/")}/{info.node_name}'
                self.foreign[gid] = name
                self.log.error(f'foreign publisher {name} (gid {gid}) on {topics.COMMAND}: only '
                               f'{source!r} may command the actuator; its commands are ignored')
        self.source_gids = gids

    def command_from_source(self, sender: str, step: int) -> bool:
        """Return True if ``sender`` (a ``header.frame_id``) is the command source's writer gid.

        An unknown sender triggers a rescan of the graph (a new source writer may
        have just matched; the graph can show it after its first messages): always
        while no source writer is known, else at most every RESCAN_S, so a flood
        of forged senders costs the running loop little.
        """
        if sender in self.source_gids:
            return True
        now = time.monotonic()
        if sender not in self.foreign and (not self.source_gids
                                           or now - self.last_scan >= RESCAN_S):
            self.last_scan = now
            self.scan_command_publishers()
            if sender in self.source_gids:
                return True
        self.foreign_rejected += 1
        if self.foreign_rejected <= 5 or self.foreign_rejected % 1000 == 0:
            who = self.foreign.get(sender, 'an unknown writer')
            self.log.warning(f'command of step {step} from {who} (sender {sender!r}) '
                             f'ignored; {self.foreign_rejected} foreign command(s) so far')
        return False

    def command_accepted(self, msg, step: int) -> bool:
        """Return True if the command ``msg`` may reach the actuator (else it is logged).

        A command of another run (its run identity, rths_common.transport) never
        does.  In a run with an identity, a command carrying it is the run's own,
        whichever writer the graph shows (a node of another run with the source's
        name cannot make the run's first command wait for a graph scan); without one
        (a bridge started by hand) the sender must be the command source's writer.
        """
        sender = self.io_in.sender(msg)
        if not self.io_in.ours(msg):    # another run's command never reaches the actuator
            if self.command_from_source(sender, step):   # else logged there as foreign
                ns.log_foreign(self.log, self.io_in, topics.COMMAND)
            return False
        return bool(self.io_in.run_id) or self.command_from_source(sender, step)

    @property
    def rejected(self) -> int:
        """Return (lock-step) the count of commands of another step than the expected one."""
        return self.driver.rejected

    def on_reject(self, step: int, expected: int):
        """Log a lock-step command of another step than the expected one."""
        self.log.warning(f'command of step {step} ignored: expected step '
                         f'{expected} (duplicate or out of order)')

    def on_command(self, msg):
        """Take the command of step k: lock-step, its tick is now; else it waits for its tick."""
        t_in = ns.now_ns()
        if self.stopped:
            return
        stamp_ns, step, (command,) = self.io_in.decode(msg)
        if not self.command_accepted(msg, step):
            return
        timing = self.timing
        timing['recv_step'].append(step)
        timing['recv_wall_ns'].append(t_in)
        timing['recv_stamp_ns'].append(stamp_ns)
        latency_us = (t_in - stamp_ns) * 1e-3
        if self.ticks is not None:
            self.offer(step, (command, latency_us))
        elif self.stop_timer is None:   # else an autonomous safe stop runs: commands ignored
            self.last_command_t = time.monotonic()
            self.driver.feed(step, (command, latency_us))

    def tick_now(self, step: int, command):
        """Lock-step tick ``step``: the command of step - D (command_delay_steps) is written."""
        self.bridge.receive(step, command)
        due = self.bridge.due(step)
        command, latency_us = (None, -1.0) if due is None else due
        return self.apply(step, command, ns.now_ns(), latency_us=latency_us)

    def on_run_steps(self, msg: UInt64):
        """Take the number of steps of the run (the clock stops there)."""
        self.n_steps = int(msg.data)

    def offer(self, step: int, command):
        """Keep the newest command for its tick; the first command starts the clock."""
        ticks = self.ticks
        if not ticks.running:
            if step != 0:
                return
            self.bridge.receive(0, command)
            self.start_clock()
            return
        if step + self.bridge.delay_steps < ticks.k:
            if step > 0:
                self.late += 1  # its tick has passed: already counted as a miss
            return
        self.bridge.receive(step, command)  # waits for tick step + D

    def start_clock(self):
        """Tick 0 is now; start the clock thread or timer if one is used."""
        self.ticks.start(time.monotonic_ns())
        prio, cpus, _ = ns.tuning(self.own, 'bridge')
        self.tuning = ns.tune_process(prio, cpus, 'default')  # threads created since
        self.cpu_loop = [time.process_time(), None]
        self.log.info('first command: clock started')
        if self.own['clock'] == 'thread':
            self.clock_thread = ns.TickThread(self.next_due_ns, self.tick).start()
        elif self.own['clock'] == 'timer':
            self.tick()
            steady = Clock(clock_type=ClockType.STEADY_TIME)
            self.clock_timer = self.node.create_timer(self.ticks.period_ns * 1e-9,
                                                      self.timer_tick,
                                                      clock=steady)

    def next_due_ns(self):
        """Monotonic time of the next tick, or None when the clock is not running.

        Once the run is over the clock stays stopped: a safe stop after it runs on
        the stop timer (:meth:`start_safe_stop`), which numbers its own steps.
        """
        ticks = self.ticks
        if ticks is None or not ticks.running or self.stopped or self.run_over:
            return None
        if self.n_steps is not None and ticks.k >= self.n_steps:
            if self.bridge.state not in (HOLD, RAMP):
                if not self.run_over:
                    self.run_over = True
                    self.cpu_loop[1] = time.process_time()
                    self.log.info(f'run complete after {ticks.k} ticks: holding the last '
                                  f'position; {self.clock.misses} deadline miss(es), '
                                  f'{self.late} late command(s), {ticks.overruns} overrun(s)')
                return None
        return ticks.due_ns()

    def timer_tick(self):
        """Run the ticks that are due (the timer clock)."""
        if self.next_due_ns() is not None:
            self.tick()

    def tick(self):
        """Tick k: write the newest command (or extrapolate: deadline miss), publish step k."""
        if lifeline.lost():
            self.on_launcher_lost()
        k, late_ns, skipped = self.ticks.take(time.monotonic_ns())
        if skipped:   # a stall: the skipped ticks are missing commands (safety.py's policy)
            self.bridge.supervisor.stalled(skipped, k)
        t_in = ns.now_ns()
        in_run = self.n_steps is None or k < self.n_steps
        due = self.bridge.due(k)   # (command, latency) of step k - D (command_delay_steps)
        if due is not None:
            (command, latency_us), missed = due, False
        else:
            command, latency_us, missed = None, -1.0, in_run
            if missed:
                self.clock.misses += 1
        timing = self.timing
        timing['tick_step'].append(k)
        timing['tick_wall_ns'].append(t_in)
        timing['tick_cpu_ns'].append(time.thread_time_ns())
        timing['tick_late_ns'].append(late_ns)
        timing['missed'].append(missed)
        self.apply(k, command, t_in, latency_us=latency_us, missed=missed)

    def save_timing(self):
        """Write the per-tick/per-command times (``timing_out``) for the loop benchmark."""
        path = self.own['timing_out']
        if not path:
            return
        data = {key: np.asarray(val, dtype=np.int64) for key, val in self.timing.items()}
        cpu = self.cpu_loop or [0.0, 0.0]
        ticks = self.ticks or TickClock(self.fs_hz)
        np.savez(path, **data, misses=self.clock.misses, late=self.late,
                 overruns=ticks.overruns, period_ns=ticks.period_ns,
                 n_steps=-1 if self.n_steps is None else self.n_steps,
                 cpu_loop_s=(cpu[1] or time.process_time()) - cpu[0])

    def apply(self, step, command, t_in, latency_us=-1.0, missed=False):
        """One step through the supervisor and the backend; publish measurement and status."""
        t0 = time.perf_counter_ns()
        result = self.bridge.step(step, command, realtime=not self.lockstep)
        state, fault = result.state, result.fault
        self.step = step
        self.publish_step(result, t_in, time.perf_counter_ns() - t0, latency_us, missed)
        if fault and not self.fault_logged:
            self.fault_logged = True
            self.log.error(f'fault at step {step}: {fault}; holding, then ramping to the safe '
                           'position')
        if state == STOPPED and not self.stopped:
            self.stopped = True  # Bridge.step has deactivated the backend
            self.settle_inactive()
            self.log.error(f'safety stop at step {step}: {fault}; backend deactivated')
        return result

    def publish_step(self, result, t_in, compute_ns, latency_us=-1.0, missed=False):
        """Publish one bridge step: measurement, status, specimen and controller counts."""
        step = result.step
        self.pub.publish(self.io_out.encode(step, result.arrays))
        self.status_pub.publish(self.io_out.status(
            'bridge', step, period_us=self.clock.period_us(t_in),
            compute_us=compute_ns * 1e-3, latency_us=latency_us,
            missed=missed, misses=self.clock.misses, safety_state=result.state,
            fault=result.fault))
        if self.controller_pub is not None:
            self.publish_controller(step)
        if self.specimen_pub is not None and result.channels:
            ch = result.channels
            spec = Specimen(step=step, table_accel=[float(ch.get('table_accel', np.nan))],
                            rel_disp=[float(ch.get('rel_disp', np.nan))],
                            rel_vel=[float(ch.get('rel_vel', np.nan))])
            spec.header.frame_id = self.io_out.status_frame
            ns.stamp(spec.header, ns.now_ns())
            self.specimen_pub.publish(spec)

    def publish_controller(self, step: int, final: bool = False):
        """Publish the controller's counts when they changed (at most 10 per second), or now."""
        backend = self.bridge.backend
        revision = getattr(backend, 'revision', 0)
        seen_revision, seen_step = self.controller_seen
        if not final and (revision == seen_revision
                          or step - seen_step < max(1, int(self.fs_hz / 10))):
            return
        self.controller_seen = (revision, step)
        counts = backend.counts() if backend is not None else {}
        msg = ControllerStatus(step=max(step, 0))
        for key, value in counts.items():
            if hasattr(msg, key):
                setattr(msg, key, type(getattr(msg, key))(value))
        msg.header.frame_id = self.io_out.status_frame
        ns.stamp(msg.header, ns.now_ns())
        self.controller_pub.publish(msg)

    # ---------------------------------------------------------------- stops
    def start_safe_stop(self, reason: str, within_s: float = None):
        """Trip the supervisor and drive hold/ramp/stop from a timer at the loop rate.

        ``within_s``: hold and ramp shortened to about that long (``Bridge.emergency_stop``).
        """
        if self.stopped:
            return
        self.bridge.emergency_stop(reason, within_s)
        self.log.warning(f'safe stop: {reason}')
        if self.ticks is not None and self.ticks.running and not self.run_over:
            return  # the clock's ticks drive hold, ramp and stop
        if self.stop_timer is None:
            self.stop_timer = self.node.create_timer(1.0 / self.fs_hz, self._stop_tick)

    def on_launcher_lost(self):
        """Stop safely within ``launcher_loss_stop_s`` once the launcher died; then the run ends."""
        if self.launcher_lost:
            return
        self.launcher_lost = True
        self.start_safe_stop(lifeline.describe(), self.launcher_loss_stop_s)

    def _stop_tick(self):
        if self.stopped:
            self.stop_timer.cancel()
            return
        self.apply(self.step + 1, None, ns.now_ns())

    def watchdog(self):
        """Lock-step watchdog: no command for watchdog_timeout_s once the run has started.

        (Every 0.1 s in either mode it also looks whether the launcher died.)
        """
        if lifeline.lost():
            self.on_launcher_lost()
        clock_running = self.ticks is not None and self.ticks.running
        if (not clock_running and self.last_command_t is None) or self.lockstep:
            self.scan_command_publishers()  # before and (lock-step) during the run
        if not self.lockstep:
            return  # the supervisor's watchdog_steps watch every tick
        if (self.last_command_t is not None and not self.stopped and self.stop_timer is None
                and time.monotonic() - self.last_command_t > self.own['watchdog_timeout_s']):
            self.start_safe_stop(f"watchdog: no command for {self.own['watchdog_timeout_s']:g} s")

    def on_estop_topic(self, msg: String):
        """Start the safe stop on an emergency-stop message."""
        self.start_safe_stop(msg.data or 'emergency stop topic')

    def on_estop_srv(self, request, response):
        """Start the safe stop on an emergency-stop service call."""
        response.accepted = True
        if self.stopped:
            response.message = 'already stopped'
        else:
            self.start_safe_stop(request.reason or 'emergency stop service')
            response.message = 'holding, then ramping to the safe position'
        return response

    # ---------------------------------------------------------------- run
    def spin(self, executor, nodes=None, is_done=None) -> bool:
        """Spin ``nodes`` (default: this node) until ``is_done()`` (default: a safety stop).

        In realtime with the ``loop`` clock this node's ticks drive the spin
        loop (:func:`rths_common.node_support.spin_clocked`): in a composed
        process the bridge is the clock of every node in it.
        """
        composed = nodes is not None
        nodes = self.node if nodes is None else nodes
        is_done = is_done or (lambda: self.stopped or self.finalized)
        if self.ticks is not None and self.own['clock'] == 'loop':
            return ns.spin_clocked(nodes, executor, self.next_due_ns, self.tick, is_done,
                                   margin_us=self.own['spin_margin_us'],
                                   ready=self.command_due if composed else None,
                                   quiet=self.quiet if composed else None)
        return ns.spin_until_done(nodes, executor, is_done)

    def command_due(self) -> bool:
        """Return True if the command the next tick writes has arrived (composed: the drain)."""
        step = self.ticks.k - self.bridge.delay_steps
        return step < 0 or step in self.bridge.delay.pending

    def park(self):
        """End of the run: an external actuator ramps to the safe position (published steps)."""
        period_s = 0.0 if self.lockstep else 1.0 / self.fs_hz

        def publish(result):     # each step as it happens: the bag's stamps are its times
            self.step = result.step
            self.publish_step(result, ns.now_ns(), 0)
        try:
            results = self.bridge.park(period_s, publish)
        except (OSError, ValueError) as err:
            self.log.error(f'ramp to the safe position at the end of the run failed: {err}')
            results = []
        if results:
            last = results[-1]
            self.log.info(f'end of the run: ramped to the safe position in {len(results)} steps '
                          f'(command {float(last.applied[0]):.6g} m), controller deactivated')
            if last.fault and not self.stopped:   # a fault's ramp the run's end cut short
                self.stopped = True
                self.log.error(f'safety stop at step {last.step}: {last.fault}; backend '
                               'deactivated')
        if self.controller_pub is not None:
            self.publish_controller(self.step, final=True)

    def finish_run(self) -> int:
        """After spinning: stop the clock, save timing, flush, log; exit code (3: safety stop)."""
        thread = getattr(self, 'clock_thread', None)
        if thread is not None:
            thread.stop()
            if thread.error is not None:
                raise thread.error
        if self.ticks is not None and not self.run_over:
            # composed with direct delivery the record can end inside the last tick and the
            # spin with it: the clock has not looked since; it says 'run complete' now
            self.next_due_ns()
        self.park()
        self.save_timing()
        ns.flush([p for p in (self.pub, self.status_pub, self.controller_pub) if p is not None])
        self.log.info(f'bridge: {self.step + 1} steps applied, {self.rejected} rejected, '
                      f'{self.foreign_rejected} foreign, '
                      f'{self.io_in.foreign} of another run, '
                      f'{self.clock.misses} deadline miss(es), '
                      f'{self.bridge.supervisor.rejoins} rejoin(s) after misses, '
                      f'final state {self.bridge.state}')
        counts = self.bridge.backend.counts() if self.bridge.backend is not None else {}
        if counts:    # an external controller's replies
            self.log.info('controller: ' + ', '.join(f'{k} {v}' for k, v in counts.items()))
        return EXIT_SAFETY_STOP if self.stopped else 0


def main(argv=None):
    """Entry point of ``ros2 run rths_actuator_bridge bridge_node``."""
    lifeline.bind()       # its launcher's death: a safe stop, then exit
    rclpy.init(args=argv if argv is not None else sys.argv)
    code = 0
    shell = None
    try:
        shell = BridgeNode()
        shell.spin(ns.make_executor(shell.own['executor']))
        code = shell.finish_run()
    except ValueError as err:
        print(f'bridge_node: error: {ns.params_file_of(argv)}{err}', file=sys.stderr)
        code = 2
    finally:
        if shell is not None:
            shell.bridge.close()
        if rclpy.ok():
            rclpy.shutdown()
    lifeline.end_if_lost(code)
    return code


if __name__ == '__main__':
    sys.exit(main())
