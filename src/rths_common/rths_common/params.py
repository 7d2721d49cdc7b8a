"""The parameter schema of the loop nodes: node-level keys, their descriptions, descriptors.

Each package keeps one registry of its core's keys (default and a description
with the unit in brackets): :data:`rths_numerical.substructure.PARAMS`,
:data:`rths_compensator.params.FILTER_PARAMS`, the bridge's ``SIM_PARAMS``,
``SAFETY_PARAMS``, ``UDP_PARAMS`` and :data:`rths_actuator_bridge.bridge.PARAMS`.
The keys that configure a node itself, not its core, are described here once
(:data:`NODE_KEYS`); each node takes the subset its ``NODE_PARAMS`` names.
:func:`rths_common.node_support.make_node` turns a schema (key -> description)
into ROS parameter descriptors, so ``ros2 param describe`` shows them.
"""

#: Parameters that configure a node itself, not its core (the union of the nodes'
#: NODE_PARAMS; test_offline_node_keys checks it), with their descriptions.
NODE_KEYS = {
    'mode': 'lockstep | realtime: lock-step exchange or the fixed-rate loop',
    'executor': 'events (rclpy EventsExecutor) | single (SingleThreadedExecutor)',
    'wait_for_subscribers': '[-] readers of the output topic to wait for before step 0',
    'status_every': '[steps] publish a LoopStatus every N steps (and on every miss)',
    'history_out': '.npz path for the response history (empty: none)',
    'timing_out': '.npz path for per-step timing of the loop benchmark (empty: none)',
    'remote_graph': 'true: the other nodes run on other hosts (docs/lab_network.md)',
    'autostart': 'configure and activate at start-up',
    'watchdog_timeout_s': '[s] lock-step: no command for this long -> safe stop',
    'clock': 'loop | thread | timer: what ticks the realtime bridge',
    'spin_margin_us': '[us] loop clock: poll the last part of each period',
    'publish_specimen': 'auto | true | false: publish /rths/specimen',
    'command_source': 'node name whose /rths/command is accepted; others are refused',
    'rt_priority': '[-] SCHED_FIFO priority in realtime mode (-1: the node default, 0: none)',
    'cpus': "CPU affinity, e.g. '1' or '0-1' ('' = all)",
    'gc': 'auto | default | freeze | disable: the Python garbage collector (auto: freeze '
          'in realtime mode)',
    'coefficients_every': '[steps] adaptive compensator: publish its coefficients every N steps',
}


def core_params(params: dict) -> dict:
    """Return ``params`` without the node-level keys."""
    return {k: v for k, v in params.items() if k not in NODE_KEYS}


def node_schema(node_params, core: dict) -> dict:
    """Return the schema (key -> description) of a node: its node-level keys and its core's.

    ``core`` maps a key to a description, or to a tuple whose last item is
    the description (the packages' registries).
    """
    schema = {key: NODE_KEYS[key] for key in node_params}
    for key, spec in core.items():
        schema[key] = spec[-1] if isinstance(spec, tuple) else str(spec)
    return schema
