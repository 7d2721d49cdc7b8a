"""Message round trips: rclpy publish -> subscribe, and rosbags write -> read (issue 2)."""

import math

import pytest

MSG_FIELDS = {
    'InterfaceDisplacement': {'step': 7, 'displacement': [0.001, -0.002]},
    'Command': {'step': 8, 'command': [1.5e-3, -2.5e-3]},
    'Measurement': {'step': 9, 'applied': [0.01], 'displacement': [0.0099], 'force': [-123.5]},
    'LoopStatus': {'node': 'bridge', 'step': 10, 'step_period_us': 976.6, 'compute_us': 12.5,
                   'latency_us': 300.0, 'deadline_missed': True, 'deadline_misses': 3,
                   'safety_state': 2, 'fault': 'stroke limit: command 0.31 m > 0.254 m'},
}


def same(a, b):
    if isinstance(a, float):
        return math.isclose(a, b)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a == b


@pytest.mark.parametrize('name', sorted(MSG_FIELDS))
def test_rosbags_write_read_round_trip(tmp_path, name):
    from rths_bringup import bagio

    store = bagio.typestore()
    msgtype = f'rths_msgs/msg/{name}'
    cls = store.types[msgtype]
    header = store.types['std_msgs/msg/Header']
    time_cls = store.types['builtin_interfaces/msg/Time']
    import numpy as np
    fields = {}
    for key, value in MSG_FIELDS[name].items():
        fields[key] = np.array(value, dtype=np.float64) if isinstance(value, list) else value
    msg = cls(header=header(stamp=time_cls(sec=1, nanosec=2), frame_id=''), **fields)
    bag = tmp_path / 'bag'
    with bagio.BagWriter(bag, {'/t': msgtype}) as writer:
        writer.write_msg('/t', 123, msg)
    [(t, back)] = bagio.read_topic(bag, '/t')
    assert t == 123
    for key, value in MSG_FIELDS[name].items():
        got = getattr(back, key)
        assert same(value, list(got) if hasattr(got, 'tolist') else got), key


def test_rclpy_publish_subscribe_round_trip():
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rths_msgs import msg as rths_msg

    rclpy.init()
    try:
        pub_node = rclpy.create_node('rt_pub')
        sub_node = rclpy.create_node('rt_sub')
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        received = {}
        pubs = {}
        for name, fields in MSG_FIELDS.items():
            cls = getattr(rths_msg, name)
            pubs[name] = (pub_node.create_publisher(cls, f'/rt/{name}', qos), cls(**fields))
            sub_node.create_subscription(cls, f'/rt/{name}',
                                         lambda m, n=name: received.setdefault(n, m), qos)
        from rclpy.executors import SingleThreadedExecutor
        ex = SingleThreadedExecutor()
        ex.add_node(pub_node)
        ex.add_node(sub_node)
        import time
        t_end = time.monotonic() + 20
        while len(received) < len(MSG_FIELDS) and time.monotonic() < t_end:
            for pub, msg in pubs.values():
                pub.publish(msg)
            ex.spin_once(timeout_sec=0.05)
        assert set(received) == set(MSG_FIELDS)
        for name, fields in MSG_FIELDS.items():
            for key, value in fields.items():
                got = getattr(received[name], key)
                assert same(value, list(got) if not isinstance(got, (int, float, str, bool))
                            else got), (name, key)
    finally:
        rclpy.shutdown()
