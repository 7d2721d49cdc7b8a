"""Direct delivery between the composed container's nodes (container.LocalPublisher).

In realtime with the loop clock the three nodes' loop messages go from one node's
publisher to the other nodes' reader callbacks by a call, not over DDS; DDS
carries them only while a reader outside the process listens, and the
container's own DDS readers then drop those copies but still get every other
publisher's messages (another run's, a second command source), as before.
"""

import time
import uuid

from rths_bringup.container import EXTERNAL_CHECK_STEPS, direct_delivery
from rths_common import topics


class FakePublisher:
    def __init__(self, topic, readers):
        self.topic_name = topic
        self.readers = readers          # DDS readers matched (the container's own included)
        self.sent = []

    def publish(self, msg):
        self.sent.append(msg)

    def get_subscription_count(self):
        return self.readers


class FakeSubscription:
    def __init__(self, topic, got):
        self.topic_name = topic
        self.callback = got.append


class FakeNode:
    def __init__(self, subscriptions):
        self.subscriptions = subscriptions


class FakeShell:
    def __init__(self, pub, subscriptions):
        self.pub = pub
        self.node = FakeNode(subscriptions)


def test_the_loop_messages_reach_the_readers_in_the_process_by_a_call():
    got_numerical, got_compensator = [], []
    bridge = FakeShell(FakePublisher(topics.MEASUREMENT, readers=2), [])
    numerical = FakeShell(FakePublisher(topics.INTERFACE_DISPLACEMENT, readers=0),
                          [FakeSubscription(topics.MEASUREMENT, got_numerical)])
    compensator = FakeShell(None, [FakeSubscription(topics.MEASUREMENT, got_compensator)])
    dds = bridge.pub
    assert [p.topic_name for p in direct_delivery([bridge, numerical, compensator])] == [
        topics.MEASUREMENT]
    assert numerical.pub.__class__.__name__ == 'FakePublisher'  # nobody in the process reads it
    for k in range(3):
        bridge.pub.publish(b'step %d' % k)
    assert got_numerical == got_compensator == [b'step 0', b'step 1', b'step 2']
    assert dds.sent == []                     # only the process's own two readers: no DDS write
    assert bridge.pub.topic_name == topics.MEASUREMENT


def test_a_reader_outside_gets_them_over_dds_and_the_process_drops_its_own_copies():
    got = []
    sub = FakeSubscription(topics.COMMAND, got)
    compensator = FakeShell(FakePublisher(topics.COMMAND, readers=2), [])   # + the live view
    bridge = FakeShell(None, [sub])
    direct_delivery([compensator, bridge])
    compensator.pub.publish(b'command 0')
    assert compensator.pub.publisher.sent == [b'command 0']   # the outside reader's copy
    sub.callback(b'command 0')           # DDS brings the copy back to the bridge: dropped
    assert got == [b'command 0']
    sub.callback(b'another run: command 0')   # any other publisher's message: as before
    assert got == [b'command 0', b'another run: command 0']


def test_the_outside_readers_are_looked_for_again_every_so_many_messages():
    got = []
    pub = FakePublisher(topics.INTERFACE_DISPLACEMENT, readers=1)
    numerical = FakeShell(pub, [])
    direct_delivery([numerical, FakeShell(None, [FakeSubscription(pub.topic_name, got)])])
    for k in range(EXTERNAL_CHECK_STEPS):
        numerical.pub.publish(k)
    pub.readers = 2                      # the live view connects
    for k in range(EXTERNAL_CHECK_STEPS, EXTERNAL_CHECK_STEPS + 3):
        numerical.pub.publish(k)
    assert pub.sent == [EXTERNAL_CHECK_STEPS, EXTERNAL_CHECK_STEPS + 1,
                        EXTERNAL_CHECK_STEPS + 2]
    assert got == list(range(EXTERNAL_CHECK_STEPS + 3))


def test_the_statuses_cross_dds_only_while_a_reader_outside_listens():
    status = FakePublisher(topics.STATUS, readers=0)
    numerical = FakeShell(FakePublisher(topics.INTERFACE_DISPLACEMENT, readers=0), [])
    numerical.status_pub = status
    assert direct_delivery([numerical]) == []            # no loop reader in the process
    for k in range(EXTERNAL_CHECK_STEPS):
        numerical.status_pub.publish(k)
    assert status.sent == []                            # nobody listens: no DDS write
    status.readers = 1                                  # the live view connects
    for k in range(EXTERNAL_CHECK_STEPS, EXTERNAL_CHECK_STEPS + 2):
        numerical.status_pub.publish(k)
    assert status.sent == [EXTERNAL_CHECK_STEPS, EXTERNAL_CHECK_STEPS + 1]
    assert numerical.status_pub.topic_name == topics.STATUS


def test_every_reader_of_a_message_gets_it_before_what_they_publish_moves():
    """The order DDS gave: the compensator reads measurement k before step k + 1 reaches it."""
    calls = []
    numerical = FakeShell(FakePublisher(topics.INTERFACE_DISPLACEMENT, readers=1), [])
    compensator = FakeShell(None, [])
    bridge = FakeShell(FakePublisher(topics.MEASUREMENT, readers=2), [])

    def numerical_reads(msg):             # its step: publishes step k + 1 at once
        calls.append(('numerical', msg))
        numerical.pub.publish(msg.replace(b'measurement', b'displacement') + b'+1')

    numerical.node.subscriptions = [FakeSubscription(topics.MEASUREMENT, [])]
    numerical.node.subscriptions[0].callback = numerical_reads
    compensator.node.subscriptions = [FakeSubscription(topics.MEASUREMENT, []),
                                      FakeSubscription(topics.INTERFACE_DISPLACEMENT, [])]
    compensator.node.subscriptions[0].callback = lambda m: calls.append(('compensator', m))
    compensator.node.subscriptions[1].callback = lambda m: calls.append(('compensator', m))
    direct_delivery([numerical, bridge, compensator])    # the container's order
    bridge.pub.publish(b'measurement k')
    assert calls == [('numerical', b'measurement k'), ('compensator', b'measurement k'),
                     ('compensator', b'displacement k+1')]


def test_the_events_executor_calls_the_callback_the_subscription_has_now():
    """The copies are dropped only if rclpy calls ``subscription.callback`` as it is now."""
    import rclpy
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor
    from std_msgs.msg import UInt64

    ctx = Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node(f'direct_{uuid.uuid4().hex[:8]}', context=ctx)
        topic = f'/rths_test_{uuid.uuid4().hex[:8]}'
        before, after = [], []
        sub = node.create_subscription(UInt64, topic, lambda m: before.append(m.data), 10)
        pub = node.create_publisher(UInt64, topic, 10)
        sub.callback = lambda m: after.append(m.data)
        executor = EventsExecutor(context=ctx)     # the container's (ns.make_executor)
        executor.add_node(node)
        pub.publish(UInt64(data=7))
        t_end = time.monotonic() + 5.0
        while not after and not before and time.monotonic() < t_end:
            executor.spin_once(timeout_sec=0.05)
        assert after == [7] and before == []
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
