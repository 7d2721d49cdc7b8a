"""QoS profiles of the loop topics, per timing mode.

lockstep: every message matters and a node acts on step k only when it has step
k's input, so topics are RELIABLE; TRANSIENT_LOCAL lets a subscriber that
matched late (DDS discovery is asynchronous) still get the step that was
published before it matched, so a run can never dead-lock at start-up.  The
history is deep (LOCKSTEP_DEPTH = 10000 samples, ~10 s of steps at the lock-step
rate) because a reliable KEEP_LAST writer (and reader) drops unacknowledged
samples once its history is full: a reader that lags (the recorder, on a busy
machine) must not lose steps (the depth's measurement: docs/nodes.md).

realtime: the newest sample is the only useful one to the loop; its readers
(:func:`loop_qos`) are BEST_EFFORT, KEEP_LAST 1, VOLATILE: no retransmissions
and no queue in the 1 kHz path.  A sample that is lost or late is a deadline
miss at the bridge (it extrapolates; see the bridge node).  The writers
(:func:`loop_writer_qos`) are RELIABLE with a deep KEEP_LAST history
(REALTIME_WRITER_DEPTH) for one reader only: the recorder, which subscribes
RELIABLE (:func:`recorder_qos`).  DDS matching (the request/offered rule, Fast
DDS as any DDS): a RELIABLE writer serves a BEST_EFFORT reader as a best-effort
one (no acknowledgements, no resends, no blocking) and a RELIABLE reader
reliably; a RELIABLE reader never matches a BEST_EFFORT writer.  So the loop's
readers see what they saw before, and a recorder that falls behind on a loaded
machine (a best-effort recorder lost a 220-step burst in the processes layout,
issue 30) gets the samples it missed resent from the writer's history.  A
KEEP_LAST writer never blocks: once its history is full it forgets the oldest
unacknowledged sample (a recorder more than REALTIME_WRITER_DEPTH steps behind
loses steps, and the review says where).  The status topic stays reliable in
both modes: it is how misses are accounted for.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: History depth of the lock-step loop topics (writers and the recorder's readers).
LOCKSTEP_DEPTH = 10000
#: History depth of the realtime loop writers and of the recorder's reliable readers:
#: ~4 s of steps at 1024 Hz, longer than Fast DDS's default heartbeat period (3 s) after
#: which a reliable reader asks for what it missed at the latest.
REALTIME_WRITER_DEPTH = 4096


def loop_qos(mode: str) -> QoSProfile:
    """Return the QoS of the interface-displacement, command and measurement topics for ``mode``."""
    if mode == 'lockstep':
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=LOCKSTEP_DEPTH,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
    if mode == 'realtime':
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                          reliability=ReliabilityPolicy.BEST_EFFORT,
                          durability=DurabilityPolicy.VOLATILE)
    raise ValueError(f"unknown timing mode {mode!r}; use 'lockstep' or 'realtime'")


def loop_writer_qos(mode: str) -> QoSProfile:
    """Return the QoS the loop topics are published with in ``mode``.

    lockstep: as :func:`loop_qos`.  realtime: RELIABLE, KEEP_LAST
    REALTIME_WRITER_DEPTH, VOLATILE: compatible with the loop's best-effort
    readers (served best-effort) and the recorder's reliable ones (served
    reliably, from the history).
    """
    if mode == 'realtime':
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=REALTIME_WRITER_DEPTH,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
    return loop_qos(mode)


#: History depth of the status topic (writers and the recorder's reader).
STATUS_DEPTH = 10000


def status_qos() -> QoSProfile:
    """Return the QoS of the status topic (publishers and the recorder alike).

    Reliable and transient-local with a deep history, for the same reason as the
    lock-step loop topics: a recorder that matches a node's status publisher late
    still gets the first steps.  KEEP_LAST never blocks the publisher.  The depth
    (10000, ~3 s of the three nodes' statuses at 1024 Hz) lets a recorder that
    lags on a loaded machine catch up without losing a status: the bridge's
    per-step miss accounting must reach the bag complete (1000 was measured to
    lose statuses in realtime runs with a load average of 4-5 on 2 cores).
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=STATUS_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def recorder_qos(mode: str) -> QoSProfile:
    """Return the QoS the recorder subscribes with: reliable, deep history, matching the writers.

    realtime: RELIABLE (the writers resend what a lagging recorder missed),
    VOLATILE, KEEP_LAST REALTIME_WRITER_DEPTH (the reader's queue holds as many
    steps as the writers keep).
    """
    if mode == 'lockstep':
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=LOCKSTEP_DEPTH,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=REALTIME_WRITER_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def run_info_qos() -> QoSProfile:
    """Return the QoS of once-per-run facts (``/rths/run_steps``): reliable, latched."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
