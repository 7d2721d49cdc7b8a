"""Numerical-substructure node: integrates the building and closes the RTHS loop.

``ros2 run rths_numerical numerical_node --ros-args --params-file config/numerical.yaml``

Publishes the interface displacement of each step on ``/rths/interface_displacement``
and consumes the measured force of that step from ``/rths/measurement``; all
physics is in :mod:`rths_numerical.substructure` (no ROS there).

Lock-step mode (``mode: lockstep``): step k+1 is computed only when the
measurement of step k has arrived, so a run is deterministic and as fast as
the machine allows.  The node waits until ``wait_for_subscribers`` readers
(compensator, recorder) have matched its publisher, publishes step 0, and
exits with code 0 after the last step.  With ``history_out`` set it saves the
substructure's history (``NumericalSubstructure.history()``) as .npz.

Realtime mode (``mode: realtime``): the actuator bridge is the clock.  The node
publishes the number of steps on ``/rths/run_steps`` (latched) and step 0 once
the graph is connected (again every 0.1 s until the first measurement comes
back: best-effort samples sent before discovery settles can be lost); then it
computes step k+1 as soon as measurement k arrives.  A measurement that never
arrives (best-effort loss) is a deadline miss here: when measurement j > k
arrives the node advances the missing steps with measured forces
*interpolated* (linearly, :mod:`rths_common.gaps`) between the last received
one and that of step j, flags them in its status and goes on.  Interpolated,
not held: both ends are known when j arrives, and a held force is off by
about force rate x dt per step, the interpolated one by at most
``max|f''| dt^2 / 2`` for one lost step.  If measurement 0 itself is lost
there is nothing to interpolate from, and the force of step j fills the
missing steps.  Stale measurements (j < k) are dropped.  After the last step
it exits 0 as in lock-step, which ends the run.  ``inject_drop_every`` = N > 0
(realtime only) does not publish the interface displacement of every N-th
step: fault injection for the tests of the compensator's miss policy.
``status_every`` = N > 1 publishes the status of every N-th step only (missed
steps always), to lighten the status traffic.  ``remote_graph: true``: the rest
of the graph is in another ROS domain behind a relay (``rths linkemu``,
distributed RTHS): the node then waits only for ``wait_for_subscribers``
reader(s) of its output and a measurement publisher before step 0.
Latency settings (``rt_priority``, ``cpus``, ``gc``) are those of
:func:`rths_common.node_support.tuning`; the loop messages travel as CDR bytes
(:mod:`rths_common.cdr`); ``timing_out`` saves per-step publish/receipt times
for ``rths bench loop``.
"""

import sys
import time

import numpy as np
import rclpy
from std_msgs.msg import UInt64

from rths_common import cdr, gaps, topics
from rths_common import node_support as ns
from rths_common.qos import loop_qos, run_info_qos, status_qos
from rths_msgs.msg import InterfaceDisplacement, LoopStatus, Measurement

#: Parameters of the node itself; every other parameter goes to make_substructure().
NODE_PARAMS = {'mode': 'lockstep', 'executor': 'events', 'wait_for_subscribers': 1,
               'remote_graph': False, 'inject_drop_every': 0,
               'history_out': '', 'timing_out': '', 'status_every': 1, **ns.TUNING_PARAMS}


class NumericalNode:
    """ROS shell around a :class:`~rths_numerical.substructure.NumericalSubstructure`."""

    def __init__(self):
        from rths_numerical.substructure import make_substructure

        self.node = ns.make_node('numerical')
        params = ns.parameters(self.node)
        own = {k: ns.param(params, k, v) for k, v in NODE_PARAMS.items()}
        for key in NODE_PARAMS:
            params.pop(key, None)
        if own['mode'] not in ('lockstep', 'realtime'):
            raise ValueError(f"numerical node: mode {own['mode']!r}: use lockstep or realtime")
        self.own = own
        self.realtime = own['mode'] == 'realtime'
        self.sub = make_substructure(params)
        self.log = self.node.get_logger()
        qos = loop_qos(own['mode'])
        self.pub = self.node.create_publisher(InterfaceDisplacement,
                                              topics.INTERFACE_DISPLACEMENT, qos)
        self.status_pub = self.node.create_publisher(LoopStatus, topics.STATUS, status_qos())
        if self.realtime:  # lean messages: CDR bytes in and out (rths_common.cdr)
            self.node.create_subscription(Measurement, topics.MEASUREMENT,
                                          self.on_measurement_raw, qos, raw=True)
        else:
            self.node.create_subscription(Measurement, topics.MEASUREMENT, self.on_measurement,
                                          qos)
        self.clock = ns.StepClock()
        self.expected = 0
        self.started = False
        self.finished = False
        self.rejected = 0
        self.failed = False
        self.t_start = None
        self.progress_steps = max(1, int(round(1.0 / self.sub.dt)))  # every simulated second
        self.stale = 0
        self.gaps = gaps.GapFiller(gaps.FORCE_ORDER)  # realtime: lost measured forces
        self.last_publish = 0.0
        self.timing = {'pub_step': [], 'pub_wall_ns': [], 'recv_step': [], 'recv_wall_ns': []}
        self.cpu_loop = None
        if self.realtime:
            self.steps_pub = self.node.create_publisher(UInt64, topics.RUN_STEPS, run_info_qos())
            self.steps_pub.publish(UInt64(data=self.sub.n_steps))
            # warm-up: the first call of every code path is slow (numpy dispatch, caches); reset()
            # rather than a deep copy: an OpenSees model lives in one global domain
            self.sub.advance(np.zeros(self.sub.n_interface))
            self.sub.reset()
            gaps.warm_up(gaps.FORCE_ORDER, n_channels=self.sub.n_interface)
            tuning = ns.tune_process(*ns.tuning(own, 'numerical'))
            self.log.info(f'realtime: {tuning}')
        self.start_timer = self.node.create_timer(0.05, self.try_start)
        self.log.info(f'numerical substructure ready: {self.sub.n_steps} steps at '
                      f'{1.0 / self.sub.dt:g} Hz, {self.sub.n_interface} interface DOF(s); '
                      f"waiting for {own['wait_for_subscribers']} subscriber(s)")

    def publish(self, step: int, displacement):
        if self.realtime:
            drop = self.own['inject_drop_every']
            if drop > 0 and step > 0 and step % drop == 0:
                return  # fault injection: this interface displacement is lost
            t_ns = ns.now_ns()
            self.pub.publish(cdr.pack_step_arrays(t_ns, step, displacement))
            self.timing['pub_step'].append(step)
            self.timing['pub_wall_ns'].append(t_ns)
            return
        msg = InterfaceDisplacement(step=step, displacement=[float(x) for x in displacement])
        ns.stamp(msg.header, ns.now_ns())
        self.pub.publish(msg)

    def try_start(self):
        """Publish step 0 once the graph is connected (realtime: until the loop runs)."""
        if self.started:
            if self.realtime and self.expected == 0 and time.monotonic() - self.last_publish > 0.1:
                self.last_publish = time.monotonic()
                self.publish(0, self.first)
            elif self.expected > 0:
                self.start_timer.cancel()
            return
        # Every loop topic must reach its consumer (and the recorder, if any) before step 0:
        # a reader that matches late would otherwise miss the first steps.
        wanted = self.own['wait_for_subscribers']
        if self.own['remote_graph']:
            # the rest of the graph is in another domain behind a relay (rths linkemu): only
            # the relay's reader of our output and its measurement publisher are visible
            if (self.pub.get_subscription_count() < wanted
                    or self.node.count_publishers(topics.MEASUREMENT) < 1
                    or (self.realtime and self.node.count_subscribers(topics.RUN_STEPS) < 1)):
                return
        elif (self.pub.get_subscription_count() < wanted
                or self.node.count_subscribers(topics.COMMAND) < wanted
                or self.node.count_subscribers(topics.MEASUREMENT) < wanted
                or self.node.count_publishers(topics.MEASUREMENT) < 1
                or self.node.count_publishers(topics.COMMAND) < 1):
            return
        if self.realtime and self.node.count_subscribers(topics.RUN_STEPS) < 1:
            return
        self.started = True
        if not self.realtime:
            self.start_timer.cancel()
        self.t_start = time.monotonic()
        self.log.info('graph connected: publishing step 0')
        self.first = self.sub.first_displacement()
        self.last_publish = time.monotonic()
        self.publish(0, self.first)

    def on_measurement(self, msg: Measurement):
        """Finish step k with its measured force and publish step k+1."""
        t_in = ns.now_ns()
        if msg.step != self.expected:
            self.rejected += 1
            self.log.warning(f'measurement of step {msg.step} ignored: expected step '
                             f'{self.expected} (duplicate or out of order)')
            return
        force = np.asarray(msg.force, dtype=float)
        if force.shape != (self.sub.n_interface,) or not np.all(np.isfinite(force)):
            self.log.error(f'step {msg.step}: measured force {list(msg.force)} is not '
                           f'{self.sub.n_interface} finite value(s); stopping the run')
            self.finished = True
            self.failed = True
            return
        t0 = time.perf_counter_ns()
        displacement = self.sub.advance(force)
        compute_us = (time.perf_counter_ns() - t0) * 1e-3
        latency_us = (t_in - ns.stamp_ns(msg.header)) * 1e-3
        self.status_pub.publish(ns.status_msg(
            'numerical', msg.step, period_us=self.clock.period_us(t_in),
            compute_us=compute_us, latency_us=latency_us, misses=self.clock.misses))
        self.expected += 1
        if self.expected % self.progress_steps == 0:
            self.log.info(f'progress: step {self.expected} of {self.sub.n_steps} '
                          f'({self.expected * self.sub.dt:.1f} s simulated)')
        if self.sub.done():
            self.finished = True
            return
        self.publish(self.expected, displacement)

    def on_measurement_raw(self, data: bytes):
        """Realtime: finish step k (interpolating over lost measurements), publish k+1."""
        t_in = ns.now_ns()
        if self.finished:
            return
        stamp_ns, step, _, _, force_values = cdr.unpack_step_arrays(data, 3)
        if step < self.expected:
            self.stale += 1
            return
        if self.cpu_loop is None:
            self.cpu_loop = [time.process_time(), None]
        self.timing['recv_step'].append(step)
        self.timing['recv_wall_ns'].append(t_in)
        force = np.array(force_values, dtype=float)
        if force.shape != (self.sub.n_interface,) or not np.all(np.isfinite(force)):
            self.log.error(f'step {step}: measured force {list(force_values)} is not '
                           f'{self.sub.n_interface} finite value(s); stopping the run')
            self.finished = True
            self.failed = True
            return
        period_us = self.clock.period_us(t_in)
        latency_us = (t_in - stamp_ns) * 1e-3
        lost = step - self.expected
        filled = self.gaps.fill(step, force)  # interpolated lost forces (none before step 0)
        while self.expected < step and not self.sub.done():
            # measurement lost: the interpolated force (or, before any, the new one)
            self.clock.misses += 1
            i = lost - (step - self.expected)
            self.sub.advance(filled[i] if len(filled) == lost else force)
            self.status_pub.publish(cdr.pack_status(
                ns.now_ns(), 'numerical', self.expected, period_us=period_us, missed=True,
                misses=self.clock.misses))
            self.expected += 1
        if self.sub.done():
            self.finish()
            return
        t0 = time.perf_counter_ns()
        displacement = self.sub.advance(force)
        compute_us = (time.perf_counter_ns() - t0) * 1e-3
        self.expected += 1
        if not self.sub.done():
            self.publish(self.expected, displacement)
        if step % self.own['status_every'] == 0:
            self.status_pub.publish(cdr.pack_status(
                ns.now_ns(), 'numerical', step, period_us=period_us, compute_us=compute_us,
                latency_us=latency_us, misses=self.clock.misses))
        if self.expected % self.progress_steps == 0:
            self.log.info(f'progress: step {self.expected} of {self.sub.n_steps} '
                          f'({self.expected * self.sub.dt:.1f} s simulated)')
        if self.sub.done():
            self.finish()

    def finish(self):
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
        wall = time.monotonic() - self.t_start if self.t_start else 0.0
        rate = self.expected / wall if wall > 0 else 0.0
        text = (f'numerical: {self.expected} of {self.sub.n_steps} steps in {wall:.2f} s '
                f'({rate:.0f} steps/s), {self.rejected} measurement(s) rejected')
        if self.realtime:
            text += (f', {self.clock.misses} measurement(s) missed (force interpolated), '
                     f'{self.stale} stale')
        return text

    def finish_run(self, done: bool) -> int:
        """After spinning: flush, log the summary, save history and timing; the exit code.

        1 if the run failed (a bad measured force), 130 if a signal stopped it
        before the last step (``done`` False), else 0.
        """
        ns.flush([self.pub, self.status_pub])
        self.log.info(self.summary())
        self.save_history()
        self.save_timing()
        if self.failed:
            return 1
        return 0 if done else 130

    def save_history(self):
        path = self.own['history_out']
        if path:
            np.savez(path, **self.sub.history())
            self.log.info(f'history written to {path}')


def main(argv=None):
    """Entry point of ``ros2 run rths_numerical numerical_node``."""
    rclpy.init(args=argv if argv is not None else sys.argv)
    code = 0
    try:
        shell = NumericalNode()
        executor = ns.make_executor(shell.own['executor'])
        done = ns.spin_until_done(shell.node, executor, lambda: shell.finished)
        code = shell.finish_run(done)
    except ValueError as err:
        print(f'numerical_node: error: {ns.params_file_of(argv)}{err}', file=sys.stderr)
        code = 2
    finally:
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
