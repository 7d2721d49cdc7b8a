"""The recorder takes what is left in its readers when the run ends (issue 30).

A supervisor kill in the processes layout (2026-11-28) left the last 1-4 messages
of each topic in the recorder's readers: the events that announced them belonged
to the run's executor, which let the node go, and the tail's executor never
heard of them.  The bags ended at RAMP, without the bridge's STOPPED.
``Recorder.take_the_rest`` takes them without any executor event.
"""

import time
import uuid

import rclpy

from rths_bringup.recorder import Recorder
from rths_common import bagio, topics
from rths_common import node_support as ns
from rths_common.qos import status_qos
from rths_common.transport import Transport

RAMP, STOPPED = 2, 3


def test_take_the_rest_takes_what_no_executor_announced_and_the_bag_keeps_it(tmp_path):
    from rths_msgs.msg import LoopStatus

    run_id = f'take-the-rest-{uuid.uuid4().hex[:8]}'   # other runs on the domain are not ours
    bag = tmp_path / 'bag'
    rclpy.init(args=['--ros-args', '-p', f'bag:={bag}', '-p', f'run_id:={run_id}'])
    try:
        rec = Recorder()
        probe = rclpy.create_node(f'bridge_{uuid.uuid4().hex[:8]}')
        pub = probe.create_publisher(LoopStatus, topics.STATUS, status_qos())
        t_end = time.monotonic() + 10.0
        while pub.get_subscription_count() < 1 and time.monotonic() < t_end:
            time.sleep(0.01)
        assert pub.get_subscription_count() >= 1, 'the recorder never matched the status writer'
        ours = Transport(LoopStatus, (), raw=False, run_id=run_id)
        states = [RAMP] * 4 + [STOPPED]
        ended = []

        def run_ends():
            # the run's executor took the first status; the rest arrive (their events are
            # queued in that executor) just as the run ends and it lets the node go
            if rec.taken == 0 or ended:
                return bool(ended) or time.monotonic() > t_end
            ended.append(True)
            for k, state in enumerate(states[1:], start=1):
                pub.publish(ours.status('bridge', 100 + k, safety_state=state))
            time.sleep(0.3)
            return True

        pub.publish(ours.status('bridge', 100, safety_state=states[0]))
        t_end = time.monotonic() + 10.0
        ns.spin_until_done(rec.node, ns.make_executor('events'), run_ends)
        assert rec.taken == 1
        rec.collect_tail(lost=False)
        assert rec.taken == len(states)
        rec.take_the_rest()                   # nothing left: it takes nothing
        assert rec.taken == len(states)
        assert rec.close() == len(states)
        probe.destroy_node()
        rec.node.destroy_node()
    finally:
        rclpy.shutdown()
    status = [(int(m.step), int(m.safety_state))
              for _, _, m in bagio.read_messages(bag, [topics.STATUS])]
    assert status == [(100 + k, s) for k, s in enumerate(states)]
