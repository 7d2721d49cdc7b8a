"""Compensator node: the ROS shell of :class:`rths_compensator.filters.MultiChannelFilter`.

``ros2 run rths_compensator compensator_node --ros-args --params-file config/compensator.yaml``

Subscribes ``/rths/interface_displacement`` and publishes ``/rths/command``, the
designed ``G = taps / denominator`` applied causally per interface DOF
(lock-step or realtime; behaviour and measurements: docs/nodes.md).

Parameter ``method`` (fir | rls_fir | ats | amb, lock-step only): an adaptive method
started from the designed taps; it also subscribes ``/rths/measurement`` and publishes
``/rths/compensator_coefficients`` (docs/adaptive.md).
"""

import sys
import time

import numpy as np
import rclpy

from rths_common import cdr, gaps, topics
from rths_common import node_support as ns
from rths_common.qos import loop_qos, status_qos
from rths_msgs.msg import Command, InterfaceDisplacement, LoopStatus

NODE_PARAMS = {'mode': 'lockstep', 'executor': 'events', 'inject_drop_every': 0,
               'inject_duplicate_every': 0, 'inject_delay_every': 0, 'inject_delay_ms': 0.0,
               'wait_for_subscribers': 1, 'loop_fs_hz': 1024.0,
               'status_every': 1, 'coefficients_every': 64,
               **ns.TUNING_PARAMS}


class CompensatorNode:
    """ROS shell around a :class:`~rths_compensator.filters.MultiChannelFilter`."""

    def __init__(self):
        from rths_compensator.params import (
            check_compensator_params,
            check_sampling_rate,
            param_schema,
            validate_filter,
        )

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
        self.filter = None  # built on the first message, when the number of DOFs is known
        self.log = self.node.get_logger()
        self.adaptive = None
        if str(params.get('method', 'fir') or 'fir') != 'fir':
            self._setup_adaptive()
        qos = loop_qos(self.own['mode'])
        self.pub = self.node.create_publisher(Command, topics.COMMAND, qos)
        self.status_pub = self.node.create_publisher(LoopStatus, topics.STATUS, status_qos())
        self.sender = ''  # this node's writer gid, in frame_id: the bridge checks the sender
        ns.wait_for_readers(self.node, self.pub, self.own['wait_for_subscribers'])
        if self.own['mode'] == 'realtime':  # lean messages: CDR bytes (rths_common.cdr)
            self.node.create_subscription(InterfaceDisplacement, topics.INTERFACE_DISPLACEMENT,
                                          self.on_displacement_raw, qos, raw=True)
        else:
            self.node.create_subscription(InterfaceDisplacement, topics.INTERFACE_DISPLACEMENT,
                                          self.on_displacement, qos)
        self.clock = ns.StepClock()
        self.expected = 0
        self.rejected = 0
        self.realtime = self.own['mode'] == 'realtime'
        self.gaps = gaps.GapFiller(gaps.DISPLACEMENT_ORDER)  # realtime: lost displacements
        self.last_out = None
        self.misses = 0
        if self.realtime:
            from rths_compensator.filters import MultiChannelFilter
            # warm-up: the first call of every code path is slow (imports, numpy dispatch)
            MultiChannelFilter(taps, denominator, n_channels=1).step(np.zeros(1))
            gaps.warm_up(gaps.DISPLACEMENT_ORDER)
            cdr.unpack_step_arrays(cdr.pack_step_arrays(0, 0, [0.0]))
            tuning = ns.tune_process(*ns.tuning(self.own, 'compensator'))
            self.log.info(f'realtime: {tuning}')
        self.log.info(f"compensator ready: scheme {self.params['scheme']}, "
                      f"{len(self.params['taps'])} taps, "
                      f"{len(self.params['denominator']) - 1} denominator order")

    def _setup_adaptive(self):
        """Adaptive method (rths_compensator.adaptive): measurements in, coefficients out."""
        from std_msgs.msg import Float64MultiArray

        from rths_compensator.adaptive import methods_from_params
        from rths_msgs.msg import Measurement

        if self.own['mode'] != 'lockstep':
            raise ValueError(f"parameter method = {self.params['method']}: the adaptive "
                             'methods run in lock-step mode only (mode: lockstep)')
        methods_from_params(self.params, 1)          # check the method and its plant now
        self.adaptive = {'pending': None, 'measured': {}}
        self.coef_pub = self.node.create_publisher(Float64MultiArray,
                                                   topics.COMPENSATOR_COEFFICIENTS,
                                                   loop_qos(self.own['mode']))
        self.node.create_subscription(Measurement, topics.MEASUREMENT, self.on_measurement,
                                      loop_qos(self.own['mode']))

    def on_measurement(self, msg):
        """Keep measurement k for the command of step k + 1 (and run it if it waits)."""
        self.adaptive['measured'][msg.step] = (list(msg.displacement), list(msg.applied))
        pending = self.adaptive['pending']
        if pending is not None and pending.step == msg.step + 1:
            self.adaptive['pending'] = None
            self.on_displacement(pending)

    def _adaptive_command(self, step, x):
        """Command of step k from the adaptive method, or None until measurement k-1 is here."""
        from std_msgs.msg import Float64MultiArray

        from rths_compensator.adaptive import methods_from_params

        measured = self.adaptive['measured']
        if step > 0 and (step - 1) not in measured:
            return None
        if self.filter is None:
            self.filter = methods_from_params(self.params, max(x.size, 1))
        prev, applied = measured.pop(step - 1, (None, None))
        command = self.filter.step(x, prev, applied)
        every = max(int(self.own['coefficients_every']), 1)
        if step % every == 0:
            self.coef_pub.publish(Float64MultiArray(data=self.filter.coefficients().tolist()))
        return command

    def sender_gid(self) -> str:
        """Return this node's writer gid on /rths/command, sent in ``header.frame_id``.

        '' until the graph shows the writer (it does by the first message); then cached.
        """
        if not self.sender:
            self.sender = ns.own_writer_gid(self.node, topics.COMMAND)
        return self.sender

    def on_displacement(self, msg: InterfaceDisplacement):
        """Filter the interface displacement of step k and publish the command of step k."""
        from rths_compensator.filters import MultiChannelFilter

        t_in = ns.now_ns()
        if msg.step != self.expected:
            self.rejected += 1
            self.log.warning(f'interface displacement of step {msg.step} ignored: expected '
                             f'step {self.expected} (duplicate or out of order)')
            return
        t0 = time.perf_counter_ns()
        x = np.asarray(msg.displacement, dtype=float)
        fault = ''
        if self.adaptive is not None:
            command = self._adaptive_command(msg.step, x)
            if command is None:            # lock-step: wait for measurement k-1
                self.adaptive['pending'] = msg
                return
            status = self.filter.status
            fault = status.reason if status.state == 'fallback' else ''
        else:
            if self.filter is None:
                self.filter = MultiChannelFilter(self.params['taps'],
                                                 self.params['denominator'],
                                                 n_channels=max(x.size, 1))
            command = self.filter.step(x)
        out = Command(step=msg.step, command=command.tolist())
        out.header.frame_id = self.sender_gid()
        ns.stamp(out.header, ns.now_ns())
        self.pub.publish(out)
        dup = self.own['inject_duplicate_every']
        if dup > 0 and msg.step > 0 and msg.step % dup == 0:
            self.pub.publish(out)  # fault injection: the same step twice
        compute_us = (time.perf_counter_ns() - t0) * 1e-3
        self.status_pub.publish(ns.status_msg(
            'compensator', msg.step, period_us=self.clock.period_us(t_in), compute_us=compute_us,
            latency_us=(t_in - ns.stamp_ns(msg.header)) * 1e-3, misses=self.clock.misses,
            fault=fault))
        self.expected += 1

    def on_displacement_raw(self, data: bytes):
        """Realtime: filter step j (interpolating over lost steps) and publish its command."""
        from rths_compensator.filters import MultiChannelFilter

        t_in = ns.now_ns()
        stamp_ns, step, values = cdr.unpack_step_arrays(data)
        if step < self.expected:
            if step == 0 and self.expected == 1 and self.last_out is not None:
                self.pub.publish(self.last_out)  # step 0 re-sent: the loop has not started
            else:
                self.rejected += 1
            return
        t0 = time.perf_counter_ns()
        x = np.array(values, dtype=float)
        if self.filter is None:
            self.filter = MultiChannelFilter(self.params['taps'], self.params['denominator'],
                                             n_channels=max(x.size, 1))
        lost = step - self.expected
        filled = self.gaps.fill(step, x)  # interpolated lost displacements (none before step 0)
        for i in range(lost):  # lost displacement(s): interpolated, or x if nothing came before
            self.filter.step(filled[i] if len(filled) == lost else x)
        self.misses += lost
        missed = lost > 0
        command = self.filter.step(x)
        delay = self.own['inject_delay_every']
        if delay > 0 and step > 0 and step % delay == 0:
            time.sleep(self.own['inject_delay_ms'] * 1e-3)  # fault injection: a delay burst
        out = cdr.pack_step_arrays(ns.now_ns(), step, command.tolist(),
                                   frame_id=self.sender_gid())
        drop = self.own['inject_drop_every']
        if not (drop > 0 and step > 0 and step % drop == 0):
            self.pub.publish(out)
        self.last_out = out
        compute_us = (time.perf_counter_ns() - t0) * 1e-3
        period_us = self.clock.period_us(t_in)
        if missed or step % self.own['status_every'] == 0:
            self.status_pub.publish(cdr.pack_status(
                ns.now_ns(), 'compensator', step, period_us=period_us, compute_us=compute_us,
                latency_us=(t_in - stamp_ns) * 1e-3, missed=missed, misses=self.misses))
        self.expected = step + 1

    def finish_run(self):
        """After spinning: flush what was published and log the count."""
        ns.flush([self.pub, self.status_pub] + ([self.coef_pub] if self.adaptive else []))
        self.log.info(f'compensator: {self.expected} steps, {self.rejected} rejected')


def main(argv=None):
    """Entry point of ``ros2 run rths_compensator compensator_node``."""
    rclpy.init(args=argv if argv is not None else sys.argv)
    code = 0
    try:
        shell = CompensatorNode()
        ns.spin_until_done(shell.node, ns.make_executor(shell.own['executor']))
        shell.finish_run()
    except ValueError as err:
        print(f'compensator_node: error: {ns.params_file_of(argv)}{err}', file=sys.stderr)
        code = 2
    finally:
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
