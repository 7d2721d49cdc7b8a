"""Issue 4: the bridge behaves like a managed (lifecycle) node.

With ``autostart: false`` it configures itself and waits INACTIVE; the standard
lifecycle services (what ``ros2 lifecycle get/set /bridge`` call) report and
change its state; transitions it does not offer are refused.
"""

from pathlib import Path
import subprocess

from rths_system_tests import REPO, graph_env


def bridge_executable() -> str:
    from ament_index_python.packages import get_package_prefix

    prefix = Path(get_package_prefix('rths_actuator_bridge'))
    return str(prefix / 'lib' / 'rths_actuator_bridge' / 'bridge_node')


class LifecycleClient:
    """A node calling ``/bridge/get_state`` and ``/bridge/change_state``."""

    def __init__(self, domain_id: int):
        from lifecycle_msgs.srv import ChangeState, GetState
        import rclpy
        from rclpy.context import Context

        self.rclpy, self.ChangeState, self.GetState = rclpy, ChangeState, GetState
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('lifecycle_client', context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.get = self.node.create_client(GetState, '/bridge/get_state')
        self.change = self.node.create_client(ChangeState, '/bridge/change_state')
        assert self.get.wait_for_service(timeout_sec=30.0), 'no /bridge/get_state'
        assert self.change.wait_for_service(timeout_sec=5.0), 'no /bridge/change_state'

    def _call(self, client, request):
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=10.0)
        assert future.result() is not None, 'no answer'
        return future.result()

    def state(self) -> str:
        return self._call(self.get, self.GetState.Request()).current_state.label

    def set(self, transition_id: int) -> bool:
        request = self.ChangeState.Request()
        request.transition.id = transition_id
        return self._call(self.change, request).success

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)


def test_bridge_waits_inactive_until_activated():
    from lifecycle_msgs.msg import Transition

    env = graph_env()
    proc = subprocess.Popen(
        [bridge_executable(), '--ros-args', '--params-file', str(REPO / 'config' / 'bridge.yaml'),
         '-p', 'autostart:=false', '-p', 'wait_for_subscribers:=0'],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    client = None
    try:
        client = LifecycleClient(int(env['ROS_DOMAIN_ID']))
        assert client.state() == 'inactive'          # configured, nothing moves
        assert not client.set(Transition.TRANSITION_CLEANUP)            # not offered
        assert not client.set(Transition.TRANSITION_DEACTIVATE)         # not active
        assert client.set(Transition.TRANSITION_ACTIVATE)
        assert client.state() == 'active'
        assert not client.set(Transition.TRANSITION_ACTIVATE)           # already active
        assert client.set(Transition.TRANSITION_DEACTIVATE)   # no command yet: plain deactivate
        assert client.state() == 'inactive'
    finally:
        if client is not None:
            client.close()
        proc.terminate()
        try:
            out, _ = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, _ = proc.communicate()
    assert 'bridge active' in out and 'bridge inactive' in out, out[-2000:]
    assert (f'lifecycle transition {Transition.TRANSITION_CLEANUP} refused in state inactive'
            in out), out[-2000:]
