"""``rths replay BAG``: republish a recorded run on its original topics with its original timing.

Any ROS tool (rqt_plot, a second recorder, a lab's own viewer) can then watch
the run again.  Messages go out as the recorded CDR bytes (no re-serialization),
spaced by their recorded receive times divided by ``--rate-scale``.
"""

import time

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.


def register(commands, benches):
    """Add ``rths replay``."""
    p = commands.add_parser(
        'replay', help='republish a recorded bag on its original topics and timing',
        description='Republish every message of a bag on its original topic, as recorded '
                    '(CDR bytes), spaced by the recorded times divided by --rate-scale. '
                    'Prints what it published per topic.')
    p.add_argument('bag', help='bag directory')
    p.add_argument('--rate-scale', type=float, default=1.0,
                   help='playback speed factor: 2 plays twice as fast (default 1)')
    p.add_argument('--topics', nargs='*', default=None, help='only these topics')
    p.add_argument('--wait-for-subscribers', type=int, default=0,
                   help='wait until every topic has this many subscribers before playing '
                        '(e.g. 1 when a recorder must catch everything; default 0)')
    p.add_argument('--wait-timeout', type=float, default=30.0,
                   help='seconds to wait for subscribers (default 30)')
    from rths_bringup import live
    live.add_arguments(p)
    p.set_defaults(func=cmd_replay)


def cmd_replay(args) -> int:
    """Run ``rths replay`` (with ``--live``, inside a live-view session)."""
    from rths_bringup import live
    from rths_common import bagio

    fs = bagio.sampling_rate(args.bag) if args.live and bagio.run_info(args.bag) else 0.0
    with live.session(args, fs_hz=fs):
        return _replay(args)


def _replay(args) -> int:
    import rclpy
    from rclpy.duration import Duration
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    from rths_common import bagio, topics
    from rths_common.node_support import message_class
    from rths_common.progress import Progress

    if not args.rate_scale > 0:
        raise ValueError(f'--rate-scale must be > 0, got {args.rate_scale}')
    reader = bagio.open_reader(args.bag)
    conns = [c for c in reader.connections
             if c.msgcount and (args.topics is None or c.topic in args.topics)]
    if not conns:
        reader.close()
        raise ValueError(f'{args.bag}: nothing to replay (no messages on the chosen topics)')
    rclpy.init()
    node = rclpy.create_node('replay')
    # reliable + transient-local: compatible with every reader (the recorder's included)
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10000,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pubs = {c.topic: node.create_publisher(message_class(c.msgtype), c.topic, qos)
            for c in conns}
    counts = dict.fromkeys(pubs, 0)
    try:
        t_end = time.monotonic() + args.wait_timeout
        # the live view reads every loop topic but /rths/specimen: wait for it there too
        wanted = {t: max(args.wait_for_subscribers,
                         int(args.live and t in topics.LOOP_TOPICS and t != topics.SPECIMEN))
                  for t in pubs}
        while any(p.get_subscription_count() < wanted[t] for t, p in pubs.items()):
            if time.monotonic() > t_end:
                raise OSError(f'not every topic reached {args.wait_for_subscribers} '
                              f'subscriber(s) within {args.wait_timeout:g} s')
            rclpy.spin_once(node, timeout_sec=0.05)
        print(f'replaying {sum(c.msgcount for c in conns)} messages on {len(pubs)} topics '
              f'at x{args.rate_scale:g}', flush=True)
        t0_bag = t0_wall = None
        bar = Progress(sum(c.msgcount for c in conns), 'replay', 'messages')
        for conn, stamp, raw in bagio.raw_messages(reader, args.bag, conns):
            bar.advance()
            if t0_bag is None:
                t0_bag, t0_wall = stamp, time.monotonic()
            wait = t0_wall + (stamp - t0_bag) * 1e-9 / args.rate_scale - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            pubs[conn.topic].publish(bytes(raw))
            counts[conn.topic] += 1
        bar.close()
        for pub in pubs.values():  # let reliable readers receive everything before exiting
            pub.wait_for_all_acked(Duration(seconds=5))
    finally:
        reader.close()
        node.destroy_node()
        rclpy.shutdown()
    for topic, n in counts.items():
        print(f'{topic:<32} {n:>8}')
    return 0
