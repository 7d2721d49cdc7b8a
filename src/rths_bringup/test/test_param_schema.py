"""The loop nodes' parameter schema: unknown keys refused, descriptors, taps at the loop rate."""

import os
from pathlib import Path
import shutil

import pytest
import rclpy
from rclpy.parameter import Parameter
import yaml

#: One unknown key per node, beside keys the node knows (a typo, and the provenance
#: of an older 'rths design' beside the compensator's filter fields).
UNKNOWN = {
    'numerical': ({'model': 'sdof', 'duration': 5.0}, 'duration'),
    'compensator': ({'scheme': 'identity', 'fs_hz': 1024.0, 'taps': [1.0],
                     'denominator': [1.0], 'solver': 'lsi'}, 'solver'),
    'bridge': ({'backend': 'simulated', 'stroke_mm': 254.0}, 'stroke_mm'),
}


def _node_class(name):
    if name == 'numerical':
        from rths_numerical.node import NumericalNode
        return NumericalNode
    if name == 'compensator':
        from rths_compensator.node import CompensatorNode
        return CompensatorNode
    from rths_actuator_bridge.node import BridgeNode
    return BridgeNode


def _init_with(tmp_path, name, params):
    path = tmp_path / f'{name}.yaml'
    path.write_text(yaml.safe_dump({name: {'ros__parameters': params}}))
    rclpy.init(args=['--ros-args', '--params-file', str(path)])


@pytest.mark.parametrize('name', list(UNKNOWN))
def test_every_loop_node_refuses_an_unknown_key(tmp_path, name):
    params, key = UNKNOWN[name]
    _init_with(tmp_path, name, dict(params, wait_for_subscribers=0))
    try:
        with pytest.raises(ValueError, match=f'unknown parameter.*{key}'):
            _node_class(name)()
    finally:
        rclpy.shutdown()


@pytest.mark.parametrize('name, key', [('numerical', 'inject_drop_every'),
                                       ('compensator', 'inject_duplicate_every')])
def test_production_nodes_refuse_fault_injection_keys(tmp_path, name, key):
    """Faults are injected by the system tests' wrapper (rths_system_tests.faults), not by keys."""
    params, _ = UNKNOWN[name]
    params = {k: v for k, v in params.items() if k not in ('duration', 'solver')}
    _init_with(tmp_path, name, dict(params, wait_for_subscribers=0, **{key: 5}))
    try:
        with pytest.raises(ValueError, match=f'unknown parameter.*{key}'):
            _node_class(name)()
    finally:
        rclpy.shutdown()


def test_node_parameters_are_described_and_read_only(tmp_path):
    from rths_common import node_support as ns
    from rths_numerical.node import NODE_PARAMS
    from rths_numerical.substructure import param_schema

    _init_with(tmp_path, 'numerical', {'fs_hz': 512.0, 'mode': 'lockstep'})
    try:
        node = ns.make_node('numerical', param_schema(NODE_PARAMS), NODE_PARAMS)
        fs = node.describe_parameter('fs_hz')
        assert fs.read_only and '[Hz]' in fs.description and fs.type == Parameter.Type.DOUBLE.value
        # a node-level key the file does not set is declared with its default
        every = node.describe_parameter('status_every')
        assert node.get_parameter('status_every').value == NODE_PARAMS['status_every']
        assert every.read_only and 'LoopStatus' in every.description
        result, = node.set_parameters([Parameter('fs_hz', value=1024.0)])
        assert not result.successful and node.get_parameter('fs_hz').value == 512.0
        node.destroy_node()
    finally:
        rclpy.shutdown()


def _config_copy(tmp_path) -> Path:
    root = Path(os.environ.get('RTHS_ROOT') or Path(__file__).resolve().parents[3])
    config = tmp_path / 'config'
    shutil.copytree(root / 'config', config)
    return config


def test_preflight_refuses_taps_designed_for_another_rate(tmp_path):
    from rths_bringup.preflight import check_config
    from rths_compensator.params import check_sampling_rate

    config = _config_copy(tmp_path)
    check_config(config)                       # the repo's config: taps at the loop rate
    numerical = config / 'numerical.yaml'
    doc = yaml.safe_load(numerical.read_text())
    doc['numerical']['ros__parameters']['fs_hz'] = 512.0
    numerical.write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match=r'compensator.yaml: field fs_hz = 1024 Hz.*512 Hz'):
        check_config(config)
    # the identity compensator holds at every rate
    check_sampling_rate({'scheme': 'identity', 'fs_hz': 1024.0}, 512.0, 'c', 'loop')
