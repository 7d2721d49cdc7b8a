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


#: One out-of-range value per node: (node, params, parameter, words of the message).
OUT_OF_RANGE = [
    ('numerical', {'model': 'sdof', 'fs_hz': 0.5}, 'fs_hz', ['[1, 100000]', '[Hz]']),
    ('bridge', {'backend': 'simulated', 'watchdog_steps': 0}, 'watchdog_steps',
     ['[1, 1000000]', '[steps]']),
    ('compensator', {'scheme': 'identity', 'taps': [1.0], 'status_every': 0}, 'status_every',
     ['[1, 1000000]', '[steps]']),
]


@pytest.mark.parametrize('name,params,key,words', OUT_OF_RANGE,
                         ids=[case[0] for case in OUT_OF_RANGE])
def test_out_of_range_value_is_refused_naming_the_parameter(tmp_path, name, params, key, words):
    _init_with(tmp_path, name, dict(params, wait_for_subscribers=0))
    try:
        with pytest.raises(ValueError, match=f'parameter {key} = .* outside its range') as info:
            _node_class(name)()
    finally:
        rclpy.shutdown()
    for word in [*words, 'fix it in the params file']:
        assert word in str(info.value), (word, str(info.value))


def test_descriptors_carry_ranges_and_no_parameter_can_be_added_at_run_time(tmp_path):
    from rcl_interfaces.msg import ParameterType

    from rths_common import node_support as ns
    from rths_numerical.node import NODE_PARAMS
    from rths_numerical.substructure import param_schema

    _init_with(tmp_path, 'numerical', {'fs_hz': 512, 'model': 'sdof'})   # an int for a float
    try:
        node = ns.make_node('numerical', param_schema(NODE_PARAMS), NODE_PARAMS)
        fs = node.describe_parameter('fs_hz')
        assert fs.type == ParameterType.PARAMETER_DOUBLE
        assert node.get_parameter('fs_hz').value == 512.0
        assert (fs.floating_point_range[0].from_value, fs.floating_point_range[0].to_value) == (
            1.0, 100_000.0)
        every = node.describe_parameter('status_every')
        assert every.integer_range[0].from_value == 1 and every.read_only
        assert not node.describe_parameter('model').floating_point_range   # no range: a name
        with pytest.raises(rclpy.exceptions.ParameterNotDeclaredException):
            node.set_parameters([Parameter('duration', value=5.0)])   # a typo at run time
        node.destroy_node()
    finally:
        rclpy.shutdown()


def test_bridge_limits_per_actuator_are_lists_in_the_params_file(tmp_path):
    """A per-channel limit: one number for all, or a list of one per actuator channel."""
    from rcl_interfaces.msg import ParameterType

    from rths_actuator_bridge.bridge import param_schema
    from rths_actuator_bridge.node import NODE_PARAMS, check_bridge_params
    from rths_common import node_support as ns

    _init_with(tmp_path, 'bridge', {'backend': 'udp', 'n_channels': 2,
                                    'stroke_m': [0.03, 0.02], 'velocity_m_s': [1, 2],
                                    'force_n': 40000.0})
    try:
        node = ns.make_node('bridge', param_schema(NODE_PARAMS), NODE_PARAMS)
        stroke = node.describe_parameter('stroke_m')
        assert stroke.type == ParameterType.PARAMETER_DOUBLE_ARRAY
        assert 'a list of one per actuator' in stroke.description
        assert stroke.floating_point_range[0].to_value == 1.0
        # a list of ints for a float limit becomes a list of floats
        assert node.describe_parameter('velocity_m_s').type == \
            ParameterType.PARAMETER_DOUBLE_ARRAY
        params = check_bridge_params(ns.parameters(node))
        assert params['stroke_m'] == [0.03, 0.02] and params['velocity_m_s'] == [1.0, 2.0]
        node.destroy_node()
    finally:
        rclpy.shutdown()
    _init_with(tmp_path, 'bridge', {'backend': 'udp', 'n_channels': 2,
                                    'stroke_m': [0.03, 2.0]})
    try:
        with pytest.raises(ValueError, match=r'parameter stroke_m\[1\] = 2.0 is outside its '
                                             r'range \[0, 1\] \[m\]'):
            ns.make_node('bridge', param_schema(NODE_PARAMS), NODE_PARAMS)
    finally:
        rclpy.shutdown()


#: Taps designed at 512 Hz (a FIR of three taps).
TAPS_512 = {'scheme': 'wls', 'fs_hz': 512.0, 'taps': [2.0, -1.5, 0.5], 'denominator': [1.0]}


def test_compensator_node_refuses_taps_for_another_loop_rate(tmp_path):
    from rths_compensator.node import CompensatorNode

    _init_with(tmp_path, 'compensator', dict(TAPS_512, wait_for_subscribers=0,
                                             loop_fs_hz=1024.0))
    try:
        with pytest.raises(ValueError) as info:
            CompensatorNode()
    finally:
        rclpy.shutdown()
    message = str(info.value)
    for word in ('fs_hz = 512 Hz', 'loop runs at 1024 Hz', 'loop_fs_hz', 'rths design',
                 'params file designed for 1024 Hz'):
        assert word in message, (word, message)
    # the same taps in a loop at their own rate, and the identity at any rate, are accepted
    for params in (dict(TAPS_512, loop_fs_hz=512.0),
                   {'scheme': 'identity', 'taps': [1.0], 'loop_fs_hz': 512.0}):
        _init_with(tmp_path, 'compensator', dict(params, wait_for_subscribers=0))
        try:
            CompensatorNode().node.destroy_node()
        finally:
            rclpy.shutdown()


def test_launcher_passes_the_loop_rate_to_the_compensator(tmp_path):
    from rths_bringup.launcher import Launcher

    config = _config_copy(tmp_path)
    numerical = config / 'numerical.yaml'
    doc = yaml.safe_load(numerical.read_text())
    doc['numerical']['ros__parameters']['fs_hz'] = 2048
    numerical.write_text(yaml.safe_dump(doc))
    assert Launcher(config).overrides['compensator']['loop_fs_hz'] == 2048.0
    # an explicit numerical override wins over the file
    over = {'numerical': {'fs_hz': 512.0}}
    assert Launcher(config, overrides=over).overrides['compensator']['loop_fs_hz'] == 512.0


def test_container_refuses_a_section_no_node_reads(tmp_path):
    from rths_bringup.container import check_sections

    good, bad = tmp_path / 'good.yaml', tmp_path / 'bad.yaml'
    good.write_text(yaml.safe_dump({'bridge': {'ros__parameters': {}},
                                    '/**': {'ros__parameters': {}}}))
    bad.write_text(yaml.safe_dump({'brige': {'ros__parameters': {'stroke_m': 0.1}}}))
    check_sections(['container', '--ros-args', '--params-file', str(good)])
    with pytest.raises(ValueError, match=r"bad.yaml: section 'brige' is no node"):
        check_sections(['container', '--ros-args', '--params-file', str(good),
                        '--params-file', str(bad)])


def test_the_parameter_table_of_docs_nodes_md_is_the_schema():
    from rths_actuator_bridge.bridge import param_schema as bridge_schema
    from rths_actuator_bridge.node import NODE_PARAMS as BRIDGE
    from rths_compensator.node import NODE_PARAMS as COMPENSATOR
    from rths_compensator.params import param_schema as compensator_schema
    from rths_numerical.node import NODE_PARAMS as NUMERICAL
    from rths_numerical.substructure import param_schema as numerical_schema

    root = Path(os.environ.get('RTHS_ROOT') or Path(__file__).resolve().parents[3])
    rows = set()
    for line in (root / 'docs' / 'nodes.md').read_text().splitlines():
        cells = [c.strip() for c in line.strip('|').split('|')]
        if len(cells) >= 3 and cells[1].startswith('`'):
            rows.add((cells[0], cells[1].strip('`'), cells[2].split(' ', 1)[1]))
    schemas = {'numerical': numerical_schema(NUMERICAL),
               'compensator': compensator_schema(COMPENSATOR), 'bridge': bridge_schema(BRIDGE)}
    want = {(node, key, '[{}, {}]'.format(*(v if isinstance(v, int) else f'{v:g}'
                                            for v in spec.range)))
            for node, schema in schemas.items() for key, spec in schema.items() if spec.range}
    assert rows == want


def test_preflight_refuses_a_value_outside_its_range(tmp_path):
    from rths_bringup.preflight import check_config

    config = _config_copy(tmp_path)
    bridge = config / 'bridge.yaml'
    doc = yaml.safe_load(bridge.read_text())
    doc['bridge']['ros__parameters']['rt_priority'] = 120   # SCHED_FIFO has 1..99
    bridge.write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError, match=r'bridge.yaml: bridge: parameter rt_priority = 120 is '
                                         r'outside its range \[-1, 99\] \[-\]'):
        check_config(config)


@pytest.mark.parametrize('text, words', [
    ('numerical:\n  ros__parameters:\n    fs_hz: [1024\n', 'not valid YAML at line 4'),
    ('numerical:\n  ros__parameters:\n    fs_hz: 1024.0\n    mode: realtime\n'
     '    fs_hz: 512.0\n', "key 'fs_hz' is given twice (lines 3 and 5)"),
])
def test_rths_launch_refuses_a_broken_or_doubled_numerical_yaml(tmp_path, text, words):
    # 'rths launch' read numerical.yaml for the timing mode before the pre-flight check and
    # ended in a YAMLError traceback; a key given twice silently took the last value
    from rths_bringup.commands import launch

    config = _config_copy(tmp_path)
    (config / 'numerical.yaml').write_text(text)
    with pytest.raises(ValueError) as err:
        launch(config, duration=1.0)
    assert str(err.value).startswith(f'{config / "numerical.yaml"}: ')
    assert words in str(err.value) and '\n' not in str(err.value)
