"""Compensator node: the ROS shell of :class:`rths_compensator.filters.MultiChannelFilter`.

``ros2 run rths_compensator compensator_node --ros-args --params-file config/compensator.yaml``

Subscribes ``/rths/interface_displacement`` and publishes ``/rths/command``, the
designed ``G = taps / denominator`` applied causally per interface DOF
(lock-step or realtime; behaviour and measurements: docs/nodes.md).

Parameter ``method`` (fir | rls_fir | ats | amb | pi_lead, lock-step or realtime): an
adaptive method started from the designed taps, or the reference PI + lead feedback
controller; these also subscribe ``/rths/measurement`` and publish
``/rths/compensator_coefficients`` (docs/adaptive.md).

Parameter ``monitor`` (off | warn | stop): the online stability monitor
(:mod:`rths_compensator.monitor`) on ``/rths/stability``; ``stop`` also stops the test
through the bridge's supervisor (``/rths/emergency_stop``) at its stop threshold.
"""

import sys
import time

import numpy as np
import rclpy
from std_msgs.msg import Float64MultiArray, String

from rths_common import gaps, lifeline, topics
from rths_common import node_support as ns
from rths_common.qos import loop_qos, loop_writer_qos, status_qos
from rths_common.stepping import Driver
from rths_common.transport import Transport
from rths_compensator.core import CompensatorCore
from rths_compensator.monitor import STOP, StabilityMonitor, settings_from_params
from rths_compensator.params import (
    check_compensator_params,
    check_filter_cost,
    check_sampling_rate,
    coupled_taps_of,
    param_schema,
    validate_filter,
)
from rths_msgs.msg import Command, InterfaceDisplacement, LoopStatus, Measurement

NODE_PARAMS = {'mode': 'lockstep', 'executor': 'events', 'wait_for_subscribers': 1,
               'wait_for_stop_readers': 1,
               'loop_fs_hz': 1024.0,
               'status_every': 1, 'coefficients_every': 64,
               **ns.TUNING_PARAMS, **ns.RUN_PARAMS}


class CompensatorNode:
    """ROS shell around a :class:`~rths_compensator.core.CompensatorCore`.

    One step path: an interface displacement (typed, or CDR bytes with
    ``mode: realtime``) becomes ``(k, x_k)``, the driver steps the core
    (lock-step: only the expected step; realtime: the newest, lost
    displacements filled by the core's policy) and the command of step k goes out.
    """

    def __init__(self):

        self.node = ns.make_node('compensator', param_schema(NODE_PARAMS), NODE_PARAMS)
        params = ns.parameters(self.node)
        self.own = {k: ns.param(params, k, v) for k, v in NODE_PARAMS.items()}
        for key in NODE_PARAMS:
            params.pop(key, None)
        check_compensator_params(params, 'compensator node parameters')
        taps, denominator, fs = validate_filter(
            'compensator node parameters', params.get('taps', []),
            params.get('denominator', [1.0]), params.get('fs_hz', 1024.0),
            params.get('scheme', ''))
        self.params = dict(params, taps=taps, denominator=denominator, fs_hz=fs)
        check_sampling_rate(self.params, self.own['loop_fs_hz'], 'compensator node parameters',
                            'loop_fs_hz: the fs_hz of numerical.yaml and bridge.yaml, which '
                            'rths launch passes')
        coupled = coupled_taps_of(self.params, 'compensator node parameters')
        if coupled is not None:
            check_filter_cost(coupled.size, self.own['loop_fs_hz'], 'compensator node '
                              'parameters (coupled_taps)')
        self.lockstep = self.own['mode'] == 'lockstep'
        self.core = CompensatorCore(self.params, realtime=not self.lockstep)
        self.driver = Driver(self.core, self.lockstep, self.on_reject)
        self.log = ns.StepLogger(self.node.get_logger())
        qos = loop_qos(self.own['mode'])
        raw = not self.lockstep   # lean messages: CDR bytes in and out (rths_common.cdr)
        run_id = self.own['run_id']
        self.io_in = Transport(InterfaceDisplacement, ('displacement',), raw, run_id)
        self.io_out = Transport(Command, ('command',), raw, run_id)
        self.adaptive = self.core.adaptive
        if self.adaptive:
            self._setup_adaptive()
        self.monitor_mode = str(self.params.get('monitor') or 'off')
        if self.monitor_mode != 'off':
            self._setup_monitor()
        self.pub = self.node.create_publisher(Command, topics.COMMAND,
                                              loop_writer_qos(self.own['mode']))
        self.status_pub = self.node.create_publisher(LoopStatus, topics.STATUS, status_qos())
        self.sender = ''  # this node's writer gid, in frame_id: the bridge checks the sender
        ns.wait_for_readers(self.node, self.pub, self.own['wait_for_subscribers'])
        if self.monitor_mode == 'stop':
            # the monitor's stop must reach the bridge, and the bag: the recorder's reader
            # is volatile (an operator's stop is too), so one matched late misses it
            ns.wait_for_readers(self.node, self.estop_pub, self.own['wait_for_stop_readers'])
        self.clock = ns.StepClock()
        self.last_out = None
        self.misses = 0
        if not self.lockstep:
            # warm-up: the first call of every code path is slow (imports, numpy dispatch)
            self.core.warm_up()
            gaps.warm_up(gaps.DISPLACEMENT_ORDER)
            self.io_in.decode(self.io_out.encode(0, (np.zeros(1),)))
            tuning = ns.tune_process(*ns.tuning(self.own, 'compensator'))
            self.log.info(f"{self.own['mode']}: {tuning}")
        # Last: the numerical node starts the run once this reader is seen, so everything
        # above (warm-up, tuning) is done before the first displacement can arrive (realtime:
        # a displacement arriving meanwhile waited tens of ms in a depth-1 queue).
        self.node.create_subscription(InterfaceDisplacement, topics.INTERFACE_DISPLACEMENT,
                                      self.on_displacement, qos, raw=raw)
        self.log.info(f"compensator ready: scheme {self.params['scheme']}, "
                      f"{len(self.params['taps'])} taps, "
                      f"{len(self.params['denominator']) - 1} denominator order"
                      + (f', coupled N x N FIR of {coupled.size} taps (coupled_taps)'
                         if coupled is not None else ''))

    @property
    def expected(self) -> int:
        """Return the step whose interface displacement comes next."""
        return self.core.next_step

    @property
    def rejected(self) -> int:
        """Return the count of displacements the driver did not step (out of order, stale)."""
        return self.driver.rejected

    def _setup_adaptive(self):
        """Adaptive method (rths_compensator.adaptive): measurements in, coefficients out."""
        # lazy: start-up cost: SciPy (~1 s), which this module needs only here
        from rths_compensator.adaptive import methods_from_params

        methods_from_params(self.params, 1)          # check the method and its plant now
        self.pending = None                          # the displacement message waiting
        self.coef_pub = self.node.create_publisher(Float64MultiArray,
                                                   topics.COMPENSATOR_COEFFICIENTS,
                                                   loop_writer_qos(self.own['mode']))
        self.io_meas = Transport(Measurement, ('applied', 'displacement'), not self.lockstep,
                                 self.own['run_id'])
        self.node.create_subscription(Measurement, topics.MEASUREMENT, self.on_measurement,
                                      loop_qos(self.own['mode']), raw=not self.lockstep)

    def _setup_monitor(self):
        """Online stability monitor (docs/monitor.md): /rths/stability, safe stop at a stop."""
        self.monitor_settings = settings_from_params(self.params)
        self.monitor_settings.check()
        self.monitors = []
        self.targets = {}
        self.monitor_stopped = False
        self.stability_pub = self.node.create_publisher(Float64MultiArray, topics.STABILITY,
                                                        status_qos())
        self.estop_pub = self.node.create_publisher(String, topics.EMERGENCY_STOP, status_qos())
        if not self.adaptive:
            self.io_meas = Transport(Measurement, ('applied', 'displacement'),
                                     not self.lockstep, self.own['run_id'])
            self.node.create_subscription(Measurement, topics.MEASUREMENT,
                                          self.on_measurement, loop_qos(self.own['mode']),
                                          raw=not self.lockstep)

    def _monitor_step(self, step: int, displacement):
        """Feed the monitor target/measured of ``step``; publish; stop the test at a stop."""
        target = self.targets.pop(step, None)
        if target is None:
            return
        if not self.monitors:
            fs = float(self.params['fs_hz'])
            self.monitors = [StabilityMonitor(fs, self.monitor_settings)
                             for _ in range(len(target))]
        pairs = zip(self.monitors, target, displacement, strict=False)
        states = [m.step(t, y) for m, t, y in pairs]
        worst = max(states, key=lambda st: st.level)
        stop = worst.level == STOP
        every = max(int(self.own['coefficients_every']), 1)
        if step % every == 0 or stop:
            self.stability_pub.publish(Float64MultiArray(data=[
                float(step), worst.delay_ms, worst.gain, worst.error_pct, worst.ti,
                float(worst.level)]))
        if stop and not self.monitor_stopped:
            self.monitor_stopped = True
            self.log.error(f'stability monitor: stop at step {step}: {worst.reason}')
            if self.monitor_mode == 'stop':
                reason = f'stability monitor: {worst.reason}'
                self.estop_pub.publish(String(data=reason))

    def on_measurement(self, msg):
        """Keep measurement k for the command of step k + 1 (lock-step: run it if it waits)."""
        if not self.io_meas.ours(msg):
            ns.log_foreign(self.log, self.io_meas, topics.MEASUREMENT)
            return
        _, step, (applied, displacement) = self.io_meas.decode(msg)
        if self.monitor_mode != 'off':
            self._monitor_step(step, displacement)
        if not self.adaptive:
            return
        result = self.core.measure(step, displacement, applied)
        if result is not None:
            self.publish(result, *self.pending)

    def sender_gid(self) -> str:
        """Return this node's writer gid on /rths/command, sent in ``header.frame_id``.

        '' until the graph shows the writer (it does by the first message); then cached.
        """
        if not self.sender:
            self.sender = ns.own_writer_gid(self.node, topics.COMMAND)
        return self.sender

    def on_reject(self, step: int, expected: int):
        """Log (lock-step) a displacement the driver did not step; re-send command 0 if due."""
        if self.lockstep:
            self.log.warning(f'interface displacement of step {step} ignored: expected '
                             f'step {expected} (duplicate or out of order)')
        elif step == 0 and expected == 1 and self.last_out is not None:
            self.driver.rejected -= 1
            self.pub.publish(self.last_out)  # step 0 re-sent: the loop has not started

    def on_displacement(self, msg):
        """Filter the interface displacement of step k (lost ones filled); publish command k."""
        t_in = ns.now_ns()
        if not self.io_in.ours(msg):
            ns.log_foreign(self.log, self.io_in, topics.INTERFACE_DISPLACEMENT)
            return
        stamp_ns, step, (x,) = self.io_in.decode(msg)
        t0 = time.perf_counter_ns()
        result = self.driver.feed(step, x)
        if result is None:
            if self.adaptive and self.core.pending is not None:
                self.pending = (t_in, stamp_ns, t0)   # lock-step: waits for measurement k-1
            return
        self.publish(result, t_in, stamp_ns, t0)

    def publish(self, result, t_in: int, stamp_ns: int, t0: int):
        """Publish the command of ``result`` and the step's status (then the coefficients).

        ``compute_us`` runs up to the command's publication: the coefficients (every
        ``coefficients_every`` steps, hundreds of values for a long FIR) go out after it,
        off the command's path.
        """
        step = result.step
        if self.monitor_mode != 'off':   # the target of this step, for the monitor
            self.targets[step] = self.core.last_target
            self.targets.pop(step - 256, None)
        out = self.io_out.encode(step, result.arrays, self.sender_gid())
        self.pub.publish(out)
        self.last_out = out
        compute_us = (time.perf_counter_ns() - t0) * 1e-3
        period_us = self.clock.period_us(t_in)
        self.misses += result.filled
        missed = result.filled > 0
        if missed or step % self.own['status_every'] == 0:
            self.status_pub.publish(self.io_out.status(
                'compensator', step, period_us=period_us, compute_us=compute_us,
                latency_us=(t_in - stamp_ns) * 1e-3, missed=missed, misses=self.misses,
                fault=result.fault))
        if self.adaptive:
            every = max(int(self.own['coefficients_every']), 1)
            if step % every == 0:
                self.coef_pub.publish(Float64MultiArray(data=self.core.coefficients().tolist()))

    def finish_run(self):
        """After spinning: flush what was published and log the count."""
        ns.flush([self.pub, self.status_pub] + ([self.coef_pub] if self.adaptive else [])
                 + ([self.stability_pub] if self.monitor_mode != 'off' else []))
        self.log.info(f'compensator: {self.expected} steps, {self.rejected} rejected')


def main(argv=None, prepare=None):
    """Entry point of ``ros2 run rths_compensator compensator_node``.

    ``prepare(shell)``, if given, is called on the constructed node before it spins.
    """
    lifeline.bind(stop=True)        # SIGTERM (a clean stop) when its launcher dies
    rclpy.init(args=argv if argv is not None else sys.argv)
    code = 0
    try:
        shell = CompensatorNode()
        if prepare is not None:
            prepare(shell)
        ns.spin_until_done(shell.node, ns.make_executor(shell.own['executor']))
        shell.finish_run()
    except ValueError as err:
        print(f'compensator_node: error: {ns.params_file_of(argv)}{err}', file=sys.stderr)
        code = 2
    finally:
        if rclpy.ok():
            rclpy.shutdown()
    lifeline.end_if_lost(code)
    return code


if __name__ == '__main__':
    sys.exit(main())
