"""Actuator-bridge node: where the numerical world touches steel.

``ros2 run rths_actuator_bridge bridge_node --ros-args --params-file config/bridge.yaml``

Subscribes ``/rths/command`` and hands each command to
:class:`rths_actuator_bridge.bridge.Bridge` (the ROS-free logic: the backend,
simulated plant or UDP servo controller, guarded by the safety supervisor);
publishes the measured displacement and force on ``/rths/measurement`` and a
``/rths/status`` message per step.

Lifecycle: the node behaves like a managed node.  It configures the backend
and the supervisor from its parameters (INACTIVE: nothing moves), then
activates them (``autostart: true``, the default).  A command is never passed
on unless the supervisor accepts it; after any fault the supervisor holds,
ramps to the safe position and stops, and the node then deactivates the
backend and exits with code 3 (the launcher reports a safety stop).

Emergency stop: a ``std_msgs/String`` on ``/rths/emergency_stop`` (the reason)
or the ``rths_msgs/srv/EmergencyStop`` service ``/rths/emergency_stop_service``.
In lock-step mode the supervisor is stepped by the incoming commands; when
none arrive for ``watchdog_timeout_s`` wall-clock seconds, or after an
emergency stop, a timer at the loop rate drives the stop sequence alone.
"""

import sys
import time

import rclpy
from std_msgs.msg import String

from rths_common import node_support as ns
from rths_common import topics
from rths_common.qos import loop_qos, status_qos
from rths_msgs.msg import Command, LoopStatus, Measurement
from rths_msgs.srv import EmergencyStop

NODE_PARAMS = {'mode': 'lockstep', 'executor': 'events', 'autostart': True,
               'watchdog_timeout_s': 5.0}
EXIT_SAFETY_STOP = 3


class BridgeNode:
    """ROS shell around a backend and its safety supervisor."""

    def __init__(self):
        from rths_actuator_bridge.bridge import Bridge

        self.node = ns.make_node('bridge')
        params = ns.parameters(self.node)
        self.own = {k: ns.param(params, k, v) for k, v in NODE_PARAMS.items()}
        for key in NODE_PARAMS:
            params.pop(key, None)
        self.log = self.node.get_logger()
        self.bridge = Bridge()
        self.bridge.configure(params)                 # configured: INACTIVE, nothing moves
        self.backend = self.bridge.backend
        self.fs_hz = self.backend.limits.fs_hz
        qos = loop_qos(self.own['mode'])
        self.pub = self.node.create_publisher(Measurement, topics.MEASUREMENT, qos)
        self.status_pub = self.node.create_publisher(LoopStatus, topics.STATUS, status_qos())
        self.node.create_subscription(Command, topics.COMMAND, self.on_command, qos)
        self.node.create_subscription(String, topics.EMERGENCY_STOP, self.on_estop_topic, 10)
        self.node.create_service(EmergencyStop, topics.EMERGENCY_STOP_SERVICE, self.on_estop_srv)
        self.clock = ns.StepClock()
        self.step = -1                 # last step written to the backend
        self.expected = 0
        self.rejected = 0
        self.last_command_t = None
        self.stopped = False
        self.stop_timer = None
        self.node.create_timer(0.1, self.watchdog)
        self.log.info(f'bridge configured: backend {params.get("backend", "simulated")}, '
                      f'{self.backend.n_channels} channel(s), stroke '
                      f'+-{self.backend.limits.stroke_m} m')
        if self.own['autostart']:
            self.activate()

    def activate(self):
        """INACTIVE -> ACTIVE: from now on commands may move the actuator."""
        self.bridge.activate()
        self.log.info('bridge active')

    # ---------------------------------------------------------------- loop
    def on_command(self, msg: Command):
        """Apply the command of step k and publish the measurement of step k."""
        t_in = ns.now_ns()
        if self.stopped:
            return
        if msg.step != self.expected:
            self.rejected += 1
            self.log.warning(f'command of step {msg.step} ignored: expected step '
                             f'{self.expected} (duplicate or out of order)')
            return
        self.expected += 1
        self.last_command_t = time.monotonic()
        if self.stop_timer is not None:
            return  # an autonomous safe stop is running; commands are ignored
        self.apply(msg.step, list(msg.command), t_in,
                   latency_us=(t_in - ns.stamp_ns(msg.header)) * 1e-3)

    def apply(self, step, command, t_in, latency_us=-1.0):
        """One step through the supervisor and the backend; publish measurement and status."""
        from rths_actuator_bridge.safety import STOPPED

        t0 = time.perf_counter_ns()
        result = self.bridge.step(step, command)
        state, fault = result.state, result.fault
        self.step = step
        out = Measurement(step=step, applied=result.applied.tolist(),
                          displacement=result.displacement.tolist(),
                          force=result.force.tolist())
        ns.stamp(out.header, ns.now_ns())
        self.pub.publish(out)
        self.status_pub.publish(ns.status_msg(
            'bridge', step, period_us=self.clock.period_us(t_in),
            compute_us=(time.perf_counter_ns() - t0) * 1e-3, latency_us=latency_us,
            misses=self.clock.misses, safety_state=state, fault=fault))
        if state == STOPPED and not self.stopped:
            self.stopped = True  # Bridge.step has deactivated the backend
            self.log.error(f'safety stop at step {step}: {fault}; backend deactivated')

    # ---------------------------------------------------------------- stops
    def start_safe_stop(self, reason: str):
        """Trip the supervisor and drive hold/ramp/stop from a timer at the loop rate."""
        if self.stopped:
            return
        self.bridge.emergency_stop(reason)
        self.log.warning(f'safe stop: {reason}')
        if self.stop_timer is None:
            self.stop_timer = self.node.create_timer(1.0 / self.fs_hz, self._stop_tick)

    def _stop_tick(self):
        if self.stopped:
            self.stop_timer.cancel()
            return
        self.apply(self.step + 1, None, ns.now_ns())

    def watchdog(self):
        """Lock-step watchdog: no command for watchdog_timeout_s once the run has started."""
        if (self.last_command_t is not None and not self.stopped and self.stop_timer is None
                and time.monotonic() - self.last_command_t > self.own['watchdog_timeout_s']):
            self.start_safe_stop(f"watchdog: no command for {self.own['watchdog_timeout_s']:g} s")

    def on_estop_topic(self, msg: String):
        self.start_safe_stop(msg.data or 'emergency stop topic')

    def on_estop_srv(self, request, response):
        response.accepted = True
        if self.stopped:
            response.message = 'already stopped'
        else:
            self.start_safe_stop(request.reason or 'emergency stop service')
            response.message = 'holding, then ramping to the safe position'
        return response


def main(argv=None):
    """Entry point of ``ros2 run rths_actuator_bridge bridge_node``."""
    rclpy.init(args=argv if argv is not None else sys.argv)
    code = 0
    shell = None
    try:
        shell = BridgeNode()
        ns.spin_until_done(shell.node, ns.make_executor(shell.own['executor']),
                           lambda: shell.stopped)
        code = EXIT_SAFETY_STOP if shell.stopped else 0
        ns.flush([shell.pub, shell.status_pub])
        shell.log.info(f'bridge: {shell.step + 1} steps applied, {shell.rejected} rejected, '
                       f'final state {shell.bridge.state}')
    except ValueError as err:
        print(f'bridge_node: error: {err}', file=sys.stderr)
        code = 2
    finally:
        if shell is not None:
            shell.bridge.close()
        if rclpy.ok():
            rclpy.shutdown()
    return code


if __name__ == '__main__':
    sys.exit(main())
