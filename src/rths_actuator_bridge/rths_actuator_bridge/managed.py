"""The bridge's ROS 2 managed node: an ``rclpy.lifecycle.LifecycleNode`` run by the bridge shell.

rclpy serves the standard lifecycle interface (``~/change_state``, ``~/get_state``,
``~/get_available_states``, ``~/get_available_transitions``,
``~/get_transition_graph`` and the ``~/transition_event`` topic), so
``ros2 lifecycle get|set|list /bridge`` sees a managed node; each transition calls
the shell's ``on_configure``, ``on_activate``, ``on_deactivate``, ``on_cleanup``,
``on_shutdown`` or ``on_error`` (:class:`rths_actuator_bridge.node.BridgeNode`).
A transition the current state does not offer is refused (``success: false``,
logged) instead of raising inside the service callback, which in this rclpy
ends the node's spin (ros2/rclpy#1209).
"""

from lifecycle_msgs.msg import State, Transition
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn


class ManagedNode(LifecycleNode):
    """A lifecycle node whose transition callbacks are those of ``shell``."""

    def __init__(self, name: str, shell, **kwargs):
        """Create the node in UNCONFIGURED; ``kwargs`` go to ``rclpy.node.Node``."""
        self.shell = shell
        super().__init__(name, **kwargs)
        service = self._service_change_state   # rclpy creates it; no public accessor
        self._change_state = service.callback
        service.callback = self._on_change_state

    def state(self) -> State:
        """Return the current primary (or transition) state."""
        state_id, label = self._state_machine.current_state
        return State(id=state_id, label=label)

    def offers(self, transition: Transition) -> bool:
        """Return True if the current state offers ``transition`` (by id, or label if given)."""
        for description in self._state_machine.available_transitions:
            transition_id, label = description[0], description[1]
            if transition.label and transition.label == label:
                return True
            if not transition.label and transition.id == transition_id:
                return True
        return False

    def _on_change_state(self, request, response):
        if not self.offers(request.transition):
            self.get_logger().warning(
                f'lifecycle transition {request.transition.label or request.transition.id} '
                f'refused in state {self.state().label}')
            response.success = False
            return response
        return self._change_state(request, response)

    def on_configure(self, state) -> TransitionCallbackReturn:
        """UNCONFIGURED -> INACTIVE (the shell's)."""
        return self.shell.on_configure(state)

    def on_activate(self, state) -> TransitionCallbackReturn:
        """INACTIVE -> ACTIVE (the shell's)."""
        return self.shell.on_activate(state)

    def on_deactivate(self, state) -> TransitionCallbackReturn:
        """ACTIVE -> INACTIVE (the shell's)."""
        return self.shell.on_deactivate(state)

    def on_cleanup(self, state) -> TransitionCallbackReturn:
        """INACTIVE -> UNCONFIGURED (the shell's)."""
        return self.shell.on_cleanup(state)

    def on_shutdown(self, state) -> TransitionCallbackReturn:
        """Any primary state -> FINALIZED (the shell's)."""
        return self.shell.on_shutdown(state)

    def on_error(self, state) -> TransitionCallbackReturn:
        """Handle a transition callback that raised: the shell decides (SUCCESS: UNCONFIGURED)."""
        return self.shell.on_error(state)
