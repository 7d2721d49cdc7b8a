"""Message round trips: rclpy publish -> subscribe, and rosbags write -> read (issue 2).

Every message of ``src/rths_msgs/msg`` and both halves of every service of
``src/rths_msgs/srv`` go through both round trips with every field set to a
value that differs from its default, the ``std_msgs/Header`` included (stamp
sec/nanosec and frame_id), so a message that loses a field or its header
fails.  A coverage test fails when a .msg/.srv gains a field (or a new file
appears) that the tables below do not exercise.
"""

import math
import time

import pytest

from rths_system_tests import REPO

MSG_DIR = REPO / 'src' / 'rths_msgs' / 'msg'
SRV_DIR = REPO / 'src' / 'rths_msgs' / 'srv'

#: Header every message carries in the round trips (none of it the default).
HEADER = {'sec': 1_700_000_123, 'nanosec': 456_789_012, 'frame_id': 'rths_test_frame'}

#: Every field of every message (header apart), each different from its default.
MSG_FIELDS = {
    'InterfaceDisplacement': {'step': 7, 'displacement': [0.001, -0.002]},
    'Command': {'step': 8, 'command': [1.5e-3, -2.5e-3]},
    'Measurement': {'step': 9, 'applied': [0.01], 'displacement': [0.0099], 'force': [-123.5]},
    'LoopStatus': {'node': 'bridge', 'step': 10, 'step_period_us': 976.6, 'compute_us': 12.5,
                   'latency_us': 300.0, 'deadline_missed': True, 'deadline_misses': 3,
                   'safety_state': 2, 'fault': 'stroke limit: command 0.31 m > 0.254 m'},
    'Specimen': {'step': 11, 'table_accel': [0.75, -0.5], 'rel_disp': [0.003, -0.001],
                 'rel_vel': [0.04, -0.02]},
    'ControllerStatus': {'step': 12, 'address': '192.168.1.20:5005', 'protocol_version': 2,
                         'replies': 10230, 'replies_lost': 21, 'replies_late': 52,
                         'replies_malformed': 1, 'replies_duplicate': 3,
                         'replies_out_of_order': 4, 'datagrams_foreign': 5, 'restarts': 1,
                         'worst_reply_ms': 2.375, 'status': 5,
                         'fault': 'controller fault at step 7: command limit: stroke'},
}

#: Every field of every service: (request, response).
SRV_FIELDS = {
    'EmergencyStop': ({'reason': 'operator pressed stop'},
                      {'accepted': True, 'message': 'stopping: hold, ramp to 0 m, deactivate'}),
}


def declared_fields(text: str) -> dict:
    """``{name: type}`` of the fields of a .msg text (comments and constants left out)."""
    fields = {}
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line or '=' in line:
            continue
        ftype, name = line.split()[:2]
        fields[name] = ftype
    return fields


def srv_parts(path) -> tuple:
    """(request text, response text) of a .srv file."""
    parts = path.read_text().split('\n---\n')
    assert len(parts) == 2, f'{path}: expected one --- line between request and response'
    return parts[0], parts[1]


def is_default(value) -> bool:
    """Return True if ``value`` equals the default a lost field would come back with."""
    if isinstance(value, list):
        return all(v == 0 for v in value)
    return value in (0, 0.0, '', False)


def same(a, b):
    if isinstance(a, float):
        return math.isclose(a, b)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def plain(value):
    """Return a received field as a Python scalar or list (numpy arrays, array.array, sequences)."""
    if isinstance(value, (bool, int, float, str)):
        return value
    if hasattr(value, 'tolist'):
        return value.tolist()
    return list(value)


def check_fields(msg, fields, where):
    for key, value in fields.items():
        assert same(value, plain(getattr(msg, key))), (where, key, getattr(msg, key))


def check_header(msg, where):
    header = msg.header
    assert (header.stamp.sec, header.stamp.nanosec, header.frame_id) == (
        HEADER['sec'], HEADER['nanosec'], HEADER['frame_id']), (where, header)


def test_every_message_and_service_field_is_covered():
    msgs = {p.stem: declared_fields(p.read_text()) for p in MSG_DIR.glob('*.msg')}
    assert set(msgs) == set(MSG_FIELDS), 'add the new message to MSG_FIELDS'
    for name, fields in msgs.items():
        assert fields.pop('header', None) == 'std_msgs/Header', f'{name}: no std_msgs/Header'
        assert set(fields) == set(MSG_FIELDS[name]), name
    srvs = {p.stem: p for p in SRV_DIR.glob('*.srv')}
    assert set(srvs) == set(SRV_FIELDS), 'add the new service to SRV_FIELDS'
    for name, path in srvs.items():
        for text, table in zip(srv_parts(path), SRV_FIELDS[name], strict=True):
            assert set(declared_fields(text)) == set(table), name
    # a field lost on the way comes back as its default: every value here must differ from it
    tables = [*MSG_FIELDS.values(), *(t for pair in SRV_FIELDS.values() for t in pair)]
    for table in tables:
        for key, value in table.items():
            assert not is_default(value), key
    assert not any(is_default(v) for v in HEADER.values())


def _rosbags_store():
    """Bagio's typestore, with the service request/response types registered as messages.

    rosbags has no .srv parser; the two halves of a .srv are .msg texts, and the
    rosidl names are ``<pkg>/srv/<Name>_Request`` / ``_Response``.
    """
    from rosbags.typesys import get_types_from_msg

    from rths_common import bagio

    store = bagio.typestore()
    types = {}
    for path in sorted(SRV_DIR.glob('*.srv')):
        for text, half in zip(srv_parts(path), ('Request', 'Response'), strict=True):
            msgtype = f'rths_msgs/srv/{path.stem}_{half}'
            if msgtype not in store.types:  # rosbags would name it <pkg>/srv/msg/<Name>
                [definition] = get_types_from_msg(text, msgtype).values()
                types[msgtype] = definition
    store.register(types)
    return store


def _rosbags_value(value):
    import numpy as np
    return np.array(value, dtype=np.float64) if isinstance(value, list) else value


def _rosbags_round_trip(tmp_path, msgtype, msg):
    from rths_common import bagio

    bag = tmp_path / 'bag'
    with bagio.BagWriter(bag, {'/t': msgtype}) as writer:
        writer.write_msg('/t', 123, msg)
    [(t, back)] = bagio.read_topic(bag, '/t')
    assert t == 123
    return back


@pytest.mark.parametrize('name', sorted(MSG_FIELDS))
def test_rosbags_write_read_round_trip(tmp_path, name):
    store = _rosbags_store()
    msgtype = f'rths_msgs/msg/{name}'
    header = store.types['std_msgs/msg/Header']
    time_cls = store.types['builtin_interfaces/msg/Time']
    fields = {k: _rosbags_value(v) for k, v in MSG_FIELDS[name].items()}
    msg = store.types[msgtype](
        header=header(stamp=time_cls(sec=HEADER['sec'], nanosec=HEADER['nanosec']),
                      frame_id=HEADER['frame_id']), **fields)
    back = _rosbags_round_trip(tmp_path, msgtype, msg)
    check_header(back, name)
    check_fields(back, MSG_FIELDS[name], name)


@pytest.mark.parametrize('name, half', [(n, h) for n in sorted(SRV_FIELDS)
                                        for h in ('Request', 'Response')])
def test_rosbags_service_round_trip(tmp_path, name, half):
    store = _rosbags_store()
    msgtype = f'rths_msgs/srv/{name}_{half}'
    fields = SRV_FIELDS[name][0 if half == 'Request' else 1]
    msg = store.types[msgtype](**{k: _rosbags_value(v) for k, v in fields.items()})
    back = _rosbags_round_trip(tmp_path, msgtype, msg)
    check_fields(back, fields, msgtype)


def _spin_until(executor, done, timeout_s=20.0):
    t_end = time.monotonic() + timeout_s
    while not done() and time.monotonic() < t_end:
        executor.spin_once(timeout_sec=0.05)


def test_rclpy_publish_subscribe_round_trip():
    from builtin_interfaces.msg import Time
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Header

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
            header = Header(stamp=Time(sec=HEADER['sec'], nanosec=HEADER['nanosec']),
                            frame_id=HEADER['frame_id'])
            pubs[name] = (pub_node.create_publisher(cls, f'/rt/{name}', qos),
                          cls(header=header, **fields))
            sub_node.create_subscription(cls, f'/rt/{name}',
                                         lambda m, n=name: received.setdefault(n, m), qos)
        ex = SingleThreadedExecutor()
        ex.add_node(pub_node)
        ex.add_node(sub_node)
        t_end = time.monotonic() + 20
        while len(received) < len(MSG_FIELDS) and time.monotonic() < t_end:
            for pub, msg in pubs.values():
                pub.publish(msg)
            ex.spin_once(timeout_sec=0.05)
        assert set(received) == set(MSG_FIELDS)
        for name, fields in MSG_FIELDS.items():
            check_header(received[name], name)
            check_fields(received[name], fields, name)
    finally:
        rclpy.shutdown()


def test_rclpy_service_round_trip():
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from rths_msgs import srv as rths_srv

    rclpy.init()
    try:
        server = rclpy.create_node('rt_srv_server')
        client_node = rclpy.create_node('rt_srv_client')
        ex = SingleThreadedExecutor()
        ex.add_node(server)
        ex.add_node(client_node)
        for name, (request, response) in SRV_FIELDS.items():
            cls = getattr(rths_srv, name)
            got = []

            def serve(req, resp, got=got, response=response):
                got.append(req)
                for key, value in response.items():
                    setattr(resp, key, value)
                return resp

            server.create_service(cls, f'/rt/srv/{name}', serve)
            client = client_node.create_client(cls, f'/rt/srv/{name}')
            _spin_until(ex, client.service_is_ready)
            assert client.service_is_ready(), name
            future = client.call_async(cls.Request(**request))
            _spin_until(ex, future.done)
            assert future.done(), f'{name}: no response within 20 s'
            assert len(got) == 1, name
            check_fields(got[0], request, f'{name} request')
            check_fields(future.result(), response, f'{name} response')
    finally:
        rclpy.shutdown()
