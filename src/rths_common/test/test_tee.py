"""The composed layout's recording tee (rths_common.tee): framing, order, bounds, loss counts."""

import os
import threading

from rths_common import topics
from rths_common.tee import TOPICS, Tee, TeePublisher, read_records


class FakePublisher:
    """Stands in for an rclpy publisher: keeps what it was given."""

    def __init__(self, topic):
        self.topic_name = topic
        self.sent = []

    def publish(self, msg):
        self.sent.append(msg)


def collect(fd, out):
    out.extend(read_records(fd))
    os.close(fd)


def test_every_record_reaches_the_reader_in_order_with_its_topic():
    r, w = os.pipe()
    got = []
    reader = threading.Thread(target=collect, args=(r, got))
    reader.start()
    tee = Tee(w, capacity=100_000, period_s=0.001)
    pubs = {t: TeePublisher(FakePublisher(t), tee)
            for t in (topics.MEASUREMENT, topics.COMMAND, topics.STATUS)}
    sent = []
    for k in range(5000):   # more than one pipe buffer and one write batch
        for topic, pub in pubs.items():
            data = f'{topic}:{k}'.encode() * (1 + k % 7)
            pub.publish(data)
            sent.append((topic, data))
    stats = tee.close()
    reader.join(10.0)
    assert stats['records'] == len(sent) and stats['dropped'] == 0
    assert [(t, d) for t, _, d in got] == sent
    stamps = [t_ns for _, t_ns, _ in got]
    assert stamps == sorted(stamps)
    assert pubs[topics.COMMAND].publisher.sent[:1] == [sent[1][1]]   # still published


def test_a_full_queue_drops_and_counts_instead_of_blocking():
    r, w = os.pipe()
    tee = Tee(w, capacity=10, period_s=60.0)   # the writer sleeps: nothing is drained
    pub = TeePublisher(FakePublisher(topics.MEASUREMENT), tee)
    for _ in range(25):
        pub.publish(b'x' * 8)
    assert tee.dropped == 15 and len(tee.queue) == 10
    got = []
    reader = threading.Thread(target=collect, args=(r, got))
    reader.start()
    stats = tee.close()
    reader.join(10.0)
    assert len(got) == 10 and stats['dropped'] == 15


def test_a_gone_recorder_is_counted_as_loss():
    r, w = os.pipe()
    os.close(r)                                 # the recorder died: EPIPE on write
    tee = Tee(w, capacity=1000, period_s=0.001)
    pub = TeePublisher(FakePublisher(topics.STATUS), tee)
    for _ in range(50):
        pub.publish(b'status')
    stats = tee.close()
    assert stats['dropped'] == 50 and stats['error']


def test_the_frame_names_every_recorded_topic():
    assert set(TOPICS) == set(topics.LOOP_TOPICS)


def test_a_message_is_recorded_before_what_publishing_it_leads_to():
    """Direct delivery: publishing measurement k runs the step that publishes step k + 1."""
    r, w = os.pipe()
    got = []
    reader = threading.Thread(target=collect, args=(r, got))
    reader.start()
    tee = Tee(w, capacity=10)
    displacement = TeePublisher(FakePublisher(topics.INTERFACE_DISPLACEMENT), tee)

    class Leads(FakePublisher):
        def publish(self, msg):
            super().publish(msg)
            displacement.publish(b'step k+1')   # the reader's step, called at once

    measurement = TeePublisher(Leads(topics.MEASUREMENT), tee)
    measurement.publish(b'measurement k')
    tee.close()
    reader.join(10.0)
    assert [(t, data) for t, _, data in got] == [(topics.MEASUREMENT, b'measurement k'),
                                                 (topics.INTERFACE_DISPLACEMENT, b'step k+1')]
