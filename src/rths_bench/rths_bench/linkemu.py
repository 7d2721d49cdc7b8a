"""A user-space network-link emulator joining two ROS domains (in the spirit of domain_bridge).

The kernel here has no ``netem`` qdisc, so the link between two labs is
emulated in user space: ``rths linkemu`` joins ROS domain A (e.g. the lab
running the numerical model) and domain B (the lab with the compensator and
the actuator bridge) and relays the loop topics between them, each message
held back by a one-way delay plus jitter, or dropped with a loss probability:

* A -> B: ``/rths/interface_displacement``, ``/rths/run_steps``, ``/rths/status``
  (the numerical node's status, so a recorder in B sees every node);
* B -> A: ``/rths/measurement``.

Messages are relayed as serialized CDR (no deserialization), first in, first
out on each direction: one link does not reorder, so the release time of a
message is ``max(previous release, arrival + delay + U(0, jitter))``.  Loss is
Bernoulli per message with a seeded generator (reproducible runs).  The
delay line is the plain-Python :class:`LinkEmulator` (unit tested); the relay
process is :func:`run_relay`.

The numerical node in domain A sees only the relay, not the rest of the graph,
so it runs with ``remote_graph: true`` (it then waits only for its own reader
and a measurement publisher).
"""

from collections import deque
import random
import signal
import threading
import time

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

#: (topic, QoS kind) relayed from domain A to domain B, and from B to A.
A_TO_B = (('/rths/interface_displacement', 'loop'), ('/rths/run_steps', 'run_info'),
          ('/rths/status', 'status'))
B_TO_A = (('/rths/measurement', 'loop'),)
#: Messages due within this time [s] are held and published in the receiving callback;
#: later ones go to the sender thread.  (3 ms held every message of a 2 ms link in the
#: callbacks, two threads polling the clock: 51 % deadline misses at 1024 Hz with the
#: delay line; 0.6 ms: 2.7 %.)
INLINE_S = 0.0006


class LinkEmulator:
    """One direction of a link: delay [s], jitter [s] (uniform, added), loss probability."""

    def __init__(self, delay_s: float = 0.0, jitter_s: float = 0.0, loss: float = 0.0,
                 seed: int = 0):
        for name, value in (('delay_s', delay_s), ('jitter_s', jitter_s)):
            if not value >= 0.0 or value > 10.0:
                raise ValueError(f'link {name} = {value} must lie in [0, 10] s')
        if not 0.0 <= loss < 1.0:
            raise ValueError(f'link loss = {loss} must lie in [0, 1) (a probability, not %)')
        self.delay_s, self.jitter_s, self.loss = float(delay_s), float(jitter_s), float(loss)
        self.rng = random.Random(seed)
        self.queue = deque()            # (release time, item), release times non-decreasing
        self.last_release = float('-inf')
        self.sent = self.lost = self.delivered = 0
        self.lock = threading.Lock()
        # held from taking due items to publishing them: the callback and the sender
        # thread both publish, and one link must not reorder
        self.out_lock = threading.Lock()

    def send(self, now: float, item, sent_at: float = None) -> bool:
        """Put ``item`` on the link at time ``now`` [s]; False if the link loses it.

        ``sent_at`` (same clock, <= now): when the sender published it; the delay
        counts from then, so the relay's own latency is part of the delay, not
        added to it.
        """
        with self.lock:
            self.sent += 1
            if self.loss and self.rng.random() < self.loss:
                self.lost += 1
                return False
            jitter = self.rng.uniform(0.0, self.jitter_s) if self.jitter_s else 0.0
            start = now if sent_at is None else min(now, sent_at)
            release = max(self.last_release, start + self.delay_s + jitter)
            self.last_release = release
            self.queue.append((release, item))
            return True

    def next_due(self):
        """Release time of the oldest message on the link, None if it is empty."""
        with self.lock:
            return self.queue[0][0] if self.queue else None

    def due(self, now: float) -> list:
        """Items whose release time has come, oldest first (removed from the link)."""
        out = []
        with self.lock:
            while self.queue and self.queue[0][0] <= now:
                out.append(self.queue.popleft()[1])
            self.delivered += len(out)
        return out

    def stats(self) -> dict:
        """Return the sent, lost and delivered datagram counts."""
        return {'sent': self.sent, 'lost': self.lost, 'delivered': self.delivered}


def _qos(kind: str, mode: str, writer: bool = False):
    """Return the QoS of a relayed topic of ``kind``: its readers', or (``writer``) its writers'."""
    from rths_common.qos import loop_qos, loop_writer_qos, run_info_qos, status_qos

    loop = loop_writer_qos if writer else loop_qos
    return {'loop': lambda: loop(mode), 'run_info': run_info_qos,
            'status': status_qos}[kind]()


def _msg_type(topic: str):
    from std_msgs.msg import UInt64

    from rths_msgs.msg import InterfaceDisplacement, LoopStatus, Measurement

    return {'/rths/interface_displacement': InterfaceDisplacement, '/rths/run_steps': UInt64,
            '/rths/status': LoopStatus, '/rths/measurement': Measurement}[topic]


class Relay:
    """The relay process: one node per domain, a delay line per direction, one sender thread."""

    def __init__(self, domain_a: int, domain_b: int, delay_s=0.0, jitter_s=0.0, loss=0.0,
                 seed=0, mode='realtime', readers_b: int = 0, timeout_s: float = 60.0):
        """Join the domains, waiting for the loop readers when asked.

        With ``readers_b`` > 0, first wait until that many readers in B
        (compensator, recorder) and one in A (numerical) match the relayed loop topics, so no
        lock-step message is relayed before its readers exist.
        """
        import rclpy
        from rclpy.context import Context

        self.rclpy = rclpy
        self.links = {'a_to_b': LinkEmulator(delay_s, jitter_s, loss, seed),
                      'b_to_a': LinkEmulator(delay_s, jitter_s, loss, seed + 1)}
        self.contexts, self.nodes, self.executors = {}, {}, {}
        for side, domain in (('a', domain_a), ('b', domain_b)):
            ctx = Context()
            rclpy.init(context=ctx, domain_id=int(domain))
            self.contexts[side] = ctx
            self.nodes[side] = rclpy.create_node(f'linkemu_{side}', context=ctx)
            # (not the EventsExecutor: its spin_once keeps the GIL while it waits, which
            # would stall the sender thread of the delay line)
            self.executors[side] = rclpy.executors.SingleThreadedExecutor(context=ctx)
            self.executors[side].add_node(self.nodes[side])
        routes = []
        for src, dst, topics in (('a', 'b', A_TO_B), ('b', 'a', B_TO_A)):
            for topic, kind in topics:
                qos = _qos(kind, mode)
                pub = self.nodes[dst].create_publisher(_msg_type(topic), topic,
                                                       _qos(kind, mode, writer=True))
                routes.append((src, dst, topic, kind, qos, pub))
        for src, _dst, topic, _kind, qos, pub in routes:   # B -> A first: B's graph arms
            if src == 'b':
                self.nodes[src].create_subscription(
                    _msg_type(topic), topic, self._forward(self.links['b_to_a'], pub,
                                                           topic != '/rths/run_steps'),
                    qos, raw=True)
        if readers_b > 0:
            wanted = {'/rths/interface_displacement': readers_b, '/rths/measurement': 1}
            t_end = time.monotonic() + timeout_s
            while any(pub.get_subscription_count() < wanted[topic]
                      for _, _, topic, _, _, pub in routes if topic in wanted):
                if time.monotonic() > t_end:
                    raise OSError(f'linkemu: the loop readers did not match within '
                                  f'{timeout_s:g} s; is the graph running in both domains?')
                for executor in self.executors.values():
                    executor.spin_once(timeout_sec=0.01)
        for src, _dst, topic, _kind, qos, pub in routes:
            if src == 'a':
                self.nodes[src].create_subscription(
                    _msg_type(topic), topic, self._forward(self.links['a_to_b'], pub,
                                                           topic != '/rths/run_steps'),
                    qos, raw=True)
        self.running = True
        self.threads = [threading.Thread(target=self._spin, args=(s,), daemon=True)
                        for s in ('a', 'b')]
        self.threads.append(threading.Thread(target=self._send, daemon=True))

    @staticmethod
    def _forward(link, pub, stamped=True):
        """Subscription callback of one route.

        The delay counts from the sender's header stamp (wall clock; hosts of one
        machine share it).  A message due within ``INLINE_S`` is held in the
        callback itself (sleeping to its release time) and published from there:
        no thread hand-over, so sub-millisecond delays are kept; later ones go
        to the sender thread.
        """
        def callback(data):
            now = time.monotonic()
            sent_at = None
            if stamped and len(data) >= 12:
                sec, nsec = int.from_bytes(data[4:8], 'little', signed=True), \
                    int.from_bytes(data[8:12], 'little')
                sent_at = now - (time.time_ns() - (sec * 1_000_000_000 + nsec)) * 1e-9
            if not link.send(now, (pub, data), sent_at):
                return
            due = link.next_due()
            while due is not None and due - time.monotonic() < INLINE_S:
                wait = due - time.monotonic()
                if wait > 0:
                    time.sleep(min(wait, 50e-6))
                    continue
                with link.out_lock:
                    for pub_, data_ in link.due(time.monotonic()):   # in order
                        pub_.publish(data_)
                due = link.next_due()
        return callback

    def _spin(self, side):
        executor = self.executors[side]
        while self.running:
            executor.spin_once(timeout_sec=0.05)

    def _send(self):
        while self.running:
            now = time.monotonic()
            for link in self.links.values():
                with link.out_lock:
                    for pub, data in link.due(now):
                        pub.publish(data)
            dues = [d for d in (link.next_due() for link in self.links.values()) if d]
            wait = min(dues) - time.monotonic() if dues else 0.0005
            time.sleep(min(max(wait, 0.0), 0.0005))

    def start(self, rt_priority: int = 0):
        """Start the threads; ``rt_priority`` > 0: SCHED_FIFO for the whole relay process."""
        for thread in self.threads:
            thread.start()
        if rt_priority > 0:
            from rths_common.node_support import tune_process
            time.sleep(0.05)
            self.tuning = tune_process(int(rt_priority), '', 'freeze')
        return self

    def stop(self):
        """Stop relaying."""
        self.running = False
        for thread in self.threads:
            thread.join(timeout=2.0)
        for side in ('a', 'b'):
            self.nodes[side].destroy_node()
            self.rclpy.shutdown(context=self.contexts[side])
        return {name: link.stats() for name, link in self.links.items()}


def run_relay(args) -> int:
    """``rths linkemu``: relay until SIGINT/SIGTERM, then print the link statistics."""
    print(f'linkemu: relaying domain {args.domain_a} <-> {args.domain_b}: delay '
          f'{args.delay_ms:g} ms + U(0, {args.jitter_ms:g}) ms, loss {args.loss_pct:g} %',
          flush=True)
    relay = Relay(args.domain_a, args.domain_b, args.delay_ms * 1e-3, args.jitter_ms * 1e-3,
                  args.loss_pct * 1e-2, args.seed, args.mode,
                  args.wait_readers).start(args.rt_priority)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print('linkemu: loop topics connected', flush=True)
    stop.wait()
    print(f'linkemu: {relay.stop()}', flush=True)
    return 0


def register(commands, benches):
    """Add ``rths linkemu``."""
    p = commands.add_parser('linkemu', help='relay the loop topics between two ROS domains '
                            'with emulated delay, jitter and loss')
    p.add_argument('--domain-a', type=int, required=True,
                   help='ROS domain of the numerical node')
    p.add_argument('--domain-b', type=int, required=True,
                   help='ROS domain of the compensator, bridge and recorder')
    p.add_argument('--delay-ms', type=float, default=0.0, help='one-way delay [ms]')
    p.add_argument('--jitter-ms', type=float, default=0.0,
                   help='jitter [ms]: uniform 0..J added to each message')
    p.add_argument('--loss-pct', type=float, default=0.0, help='loss probability [%%]')
    p.add_argument('--seed', type=int, default=1)
    p.add_argument('--mode', default='realtime', choices=('realtime', 'lockstep'))
    p.add_argument('--wait-readers', type=int, default=0,
                   help='relay nothing until this many readers in domain B (compensator, '
                        'recorder) and the numerical node in A match (lock-step runs)')
    p.add_argument('--rt-priority', type=int, default=0,
                   help='SCHED_FIFO priority of the relay (0: normal scheduling)')
    p.set_defaults(func=run_relay)
