"""Numerical-substructure node: the ROS shell of :mod:`rths_numerical.substructure`.

``ros2 run rths_numerical numerical_node --ros-args --params-file config/numerical.yaml``

Publishes the interface displacement of each step on ``/rths/interface_displacement``
and advances the substructure with the measured force of ``/rths/measurement``
(lock-step or realtime; behaviour and measurements: docs/nodes.md).
"""

import sys
import time

import numpy as np
import rclpy
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String, UInt64

from rths_common import gaps, lifeline, topics
from rths_common import node_support as ns
from rths_common.qos import loop_qos, loop_writer_qos, run_info_qos, status_qos
from rths_common.stepping import Driver
from rths_common.transport import Transport
from rths_msgs.msg import InterfaceDisplacement, LoopStatus, Measurement
from rths_numerical.inputs import inputs_text, response_chunks, response_table
from rths_numerical.stepping import NumericalCore

#: Parameters of the node itself; every other parameter goes to make_substructure().
NODE_PARAMS = {'mode': 'lockstep', 'executor': 'events', 'wait_for_subscribers': 1,
               'remote_graph': False,
               'history_out': '', 'timing_out': '', 'status_every': 1, **ns.TUNING_PARAMS,
               **ns.RUN_PARAMS}


class NumericalNode:
    """ROS shell around a :class:`~rths_numerical.stepping.NumericalCore`.

    One step path: a measurement (typed, or CDR bytes with ``mode: realtime``)
    becomes ``(k, force_k)`` (:class:`rths_common.transport.Transport`), the
    driver steps the core (lock-step: only the expected step; realtime: the
    newest step, lost forces filled by the core's policy) and the interface
    displacement of step k + 1 goes out.
    """

    def __init__(self):
        # lazy: start-up cost: SciPy (~1 s), which this module needs only here
        from rths_numerical.substructure import make_substructure, param_schema

        self.node = ns.make_node('numerical', param_schema(NODE_PARAMS), NODE_PARAMS)
        params = ns.parameters(self.node)
        own = {k: ns.param(params, k, v) for k, v in NODE_PARAMS.items()}
        for key in NODE_PARAMS:
            params.pop(key, None)
        if own['mode'] not in ('lockstep', 'realtime'):
            raise ValueError(f"numerical node: mode {own['mode']!r}: use lockstep or realtime")
        self.own = own
        self.lockstep = own['mode'] == 'lockstep'
        self.sub = make_substructure(params)
        self.core = NumericalCore(self.sub)
        self.driver = Driver(self.core, self.lockstep, self.on_reject)
        self.log = ns.StepLogger(self.node.get_logger())
        qos = loop_qos(own['mode'])
        raw = not self.lockstep   # lean messages: CDR bytes in and out (rths_common.cdr)
        run_id = own['run_id']
        self.io_in = Transport(Measurement, ('applied', 'displacement', 'force'), raw, run_id)
        self.io_out = Transport(InterfaceDisplacement, ('displacement',), raw, run_id)
        self.pub = self.node.create_publisher(InterfaceDisplacement,
                                              topics.INTERFACE_DISPLACEMENT,
                                              loop_writer_qos(own['mode']))
        self.status_pub = self.node.create_publisher(LoopStatus, topics.STATUS, status_qos())
        self.inputs_pub = self.node.create_publisher(String, topics.RUN_INPUTS, status_qos())
        self.response_pub = self.node.create_publisher(Float64MultiArray, topics.RESPONSE,
                                                       status_qos())
        self.node.create_subscription(Measurement, topics.MEASUREMENT, self.on_measurement, qos,
                                      raw=raw)
        self.clock = ns.StepClock()
        self.started = False
        self.finished = False
        self.failed = False
        self.t_start = None
        self.progress_steps = max(1, int(round(1.0 / self.sub.dt)))  # every simulated second
        self.last_publish = 0.0
        self.timing = {'pub_step': [], 'pub_wall_ns': [], 'recv_step': [], 'recv_wall_ns': []}
        self.cpu_loop = None
        if not self.lockstep:
            self.steps_pub = self.node.create_publisher(UInt64, topics.RUN_STEPS, run_info_qos())
            self.steps_pub.publish(UInt64(data=self.sub.n_steps))
            # warm-up: the first call of every code path is slow (numpy dispatch, caches); reset()
            # rather than a deep copy: an OpenSees model lives in one global domain
            self.core.step(0, np.zeros(self.sub.n_interface))
            self.core.reset()
            gaps.warm_up(gaps.FORCE_ORDER, n_channels=self.sub.n_interface)
            tuning = ns.tune_process(*ns.tuning(own, 'numerical'))
            self.log.info(f'{own["mode"]}: {tuning}')
        if self.sub.motion is not None:    # what the run will apply, before it starts
            self.log.info(self.sub.motion.describe().replace('\n', ';'))
        self.start_timer = self.node.create_timer(0.05, self.try_start)
        divisor = getattr(self.sub, 'divisor', 1)     # multirate.MultiRateSubstructure
        every = (f' (integrated every {divisor} steps, at {1.0 / self.sub.dt / divisor:g} Hz)'
                 if divisor > 1 else '')
        self.log.info(f'numerical substructure ready: {self.sub.n_steps} steps at '
                      f'{1.0 / self.sub.dt:g} Hz{every}, {self.sub.n_interface} interface DOF(s); '
                      f"waiting for {own['wait_for_subscribers']} subscriber(s)")

    @property
    def rejected(self) -> int:
        """Return (lock-step) the count of measurements of another step than the expected one."""
        return self.driver.rejected if self.lockstep else 0

    @property
    def stale(self) -> int:
        """Return (realtime) the count of measurements of a step already passed."""
        return 0 if self.lockstep else self.driver.rejected

    @property
    def expected(self) -> int:
        """Return the step whose measurement comes next (= steps finished)."""
        return self.core.next_step

    def publish(self, step: int, displacement):
        """Publish the interface displacement of ``step``."""
        self.timing['pub_step'].append(step)
        self.timing['pub_wall_ns'].append(ns.now_ns())
        self.pub.publish(self.io_out.encode(step, (displacement,)))

    def try_start(self):
        """Publish step 0 once the graph is connected (realtime: until the loop runs)."""
        if self.started:
            if (not self.lockstep and self.expected == 0
                    and time.monotonic() - self.last_publish > 0.1):
                self.last_publish = time.monotonic()
                self.publish(0, self.first)
            elif self.expected > 0:
                self.start_timer.cancel()
            return
        if not self.graph_connected():
            return
        self.started = True
        if self.lockstep:
            self.start_timer.cancel()
        self.t_start = time.monotonic()
        self.log.info('graph connected: publishing step 0')
        if getattr(self.sub, 'motion', None) is not None:
            self.inputs_pub.publish(String(data=inputs_text(self.sub, self.own['run_id'])))
        self.first = self.core.first_displacement()
        self.last_publish = time.monotonic()
        self.publish(0, self.first)

    def graph_connected(self) -> bool:
        """Return True once every loop topic reaches its consumer (and the recorder, if any).

        A reader that matches late would otherwise miss the first steps.
        """
        wanted = self.own['wait_for_subscribers']
        run_steps = self.lockstep or self.node.count_subscribers(topics.RUN_STEPS) >= 1
        if self.own['remote_graph']:
            # the rest of the graph is in another domain behind a relay (rths linkemu): only
            # the relay's reader of our output and its measurement publisher are visible
            return (self.pub.get_subscription_count() >= wanted
                    and self.node.count_publishers(topics.MEASUREMENT) >= 1 and run_steps)
        return (self.pub.get_subscription_count() >= wanted
                and self.node.count_subscribers(topics.COMMAND) >= wanted
                and self.node.count_subscribers(topics.MEASUREMENT) >= wanted
                and self.node.count_publishers(topics.MEASUREMENT) >= 1
                and self.node.count_publishers(topics.COMMAND) >= 1 and run_steps)

    def on_reject(self, step: int, expected: int):
        """Log a measurement the driver did not step: out of order (lock-step) or stale."""
        if self.lockstep:
            self.log.warning(f'measurement of step {step} ignored: expected step '
                             f'{expected} (duplicate or out of order)')

    def on_measurement(self, msg):
        """Finish step k with its measured force (lost ones filled) and publish step k + 1."""
        t_in = ns.now_ns()
        if self.finished or not self.started:
            return  # before step 0 is out, a measurement cannot be of this run
        if not self.io_in.ours(msg):
            ns.log_foreign(self.log, self.io_in, topics.MEASUREMENT)
            return
        stamp_ns, step, (_, _, force) = self.io_in.decode(msg)
        expected = self.core.policy.next_step
        if step >= expected:
            if self.cpu_loop is None:
                self.cpu_loop = [time.process_time(), None]
            self.timing['recv_step'].append(step)
            self.timing['recv_wall_ns'].append(t_in)
        t0 = time.perf_counter_ns()
        try:
            result = self.driver.feed(step, force)
        except ValueError as err:
            self.log.error(f'{err}; stopping the run')
            self.finished = True
            self.failed = True
            return
        if result is None:
            return
        compute_us = (time.perf_counter_ns() - t0) * 1e-3
        period_us = self.clock.period_us(t_in)
        for lost in range(expected, expected + result.filled):   # lost: force filled
            self.clock.misses += 1
            self.status_pub.publish(self.io_out.status(
                'numerical', lost, period_us=period_us, missed=True, misses=self.clock.misses))
        if result.filled < step - expected:   # the run ended inside the gap
            self.finish()
            return
        if result.arrays:
            self.publish(step + 1, result.output)
        if step % self.own['status_every'] == 0:
            self.status_pub.publish(self.io_out.status(
                'numerical', step, period_us=period_us, compute_us=compute_us,
                latency_us=(t_in - stamp_ns) * 1e-3, misses=self.clock.misses))
        if (step + 1) % self.progress_steps == 0:
            self.log.info(f'progress: step {step + 1} of {self.sub.n_steps} '
                          f'({(step + 1) * self.sub.dt:.1f} s simulated)')
        if result.done:
            self.finish()

    def finish(self):
        """Mark the run finished (the last step is done)."""
        self.finished = True
        if self.cpu_loop is not None:
            self.cpu_loop[1] = time.process_time()

    def save_timing(self):
        """Write per-step publish/receipt times (``timing_out``) for the loop benchmark."""
        path = self.own['timing_out']
        if path:
            cpu = self.cpu_loop or [0.0, 0.0]
            np.savez(path, **{k: np.asarray(v, dtype=np.int64) for k, v in self.timing.items()},
                     misses=self.clock.misses, stale=self.stale,
                     cpu_loop_s=(cpu[1] or time.process_time()) - cpu[0])

    def summary(self) -> str:
        """Return the one-line summary of the run."""
        wall = time.monotonic() - self.t_start if self.t_start else 0.0
        rate = self.expected / wall if wall > 0 else 0.0
        text = (f'numerical: {self.expected} of {self.sub.n_steps} steps in {wall:.2f} s '
                f'({rate:.0f} steps/s), {self.rejected} measurement(s) rejected')
        if not self.lockstep:
            text += (f', {self.clock.misses} measurement(s) missed (force interpolated), '
                     f'{self.stale} stale')
        return text

    def finish_run(self, done: bool) -> int:
        """After spinning: flush, log the summary, save history and timing; the exit code.

        1 if the run failed (a bad measured force), 130 if a signal stopped it
        before the last step (``done`` False), else 0.
        """
        self.publish_response()
        ns.flush([self.pub, self.status_pub, self.inputs_pub, self.response_pub])
        self.log.info(self.summary())
        self.save_history()
        self.save_timing()
        if self.failed:
            return 1
        return 0 if done else 130

    def publish_response(self):
        """Publish the whole structure's response of the finished steps (/rths/response)."""
        if not hasattr(self.sub, 'history') or getattr(self.sub, 'motion', None) is None:
            return
        columns, table = response_table(self.sub)
        for first, data, shape, run_id, names in response_chunks(columns, table,
                                                                 self.own['run_id']):
            msg = Float64MultiArray(data=data)
            msg.layout.dim = [MultiArrayDimension(label=run_id, size=shape[0],
                                                  stride=shape[0] * shape[1]),
                              MultiArrayDimension(label=names, size=shape[1], stride=shape[1])]
            msg.layout.data_offset = first
            self.response_pub.publish(msg)

    def save_history(self):
        """Write the response history (``history_out``), if asked."""
        path = self.own['history_out']
        if path:
            np.savez(path, **self.sub.history())
            self.log.info(f'history written to {path}')


def main(argv=None, prepare=None):
    """Entry point of ``ros2 run rths_numerical numerical_node``.

    ``prepare(shell)``, if given, is called on the constructed node before it spins.
    """
    lifeline.bind(stop=True)        # SIGTERM (a clean stop) when its launcher dies
    rclpy.init(args=argv if argv is not None else sys.argv)
    code = 0
    try:
        shell = NumericalNode()
        if prepare is not None:
            prepare(shell)
        executor = ns.make_executor(shell.own['executor'])
        done = ns.spin_until_done(shell.node, executor, lambda: shell.finished)
        code = shell.finish_run(done)
    except ValueError as err:
        print(f'numerical_node: error: {ns.params_file_of(argv)}{err}', file=sys.stderr)
        code = 2
    finally:
        if rclpy.ok():
            rclpy.shutdown()
    lifeline.end_if_lost(code)
    return code


if __name__ == '__main__':
    sys.exit(main())
