"""QoS profiles of the loop topics, per timing mode.

lockstep: every message matters and a node acts on step k only when it has step
k's input, so topics are RELIABLE; TRANSIENT_LOCAL lets a subscriber that
matched late (DDS discovery is asynchronous) still get the step that was
published before it matched, so a run can never dead-lock at start-up.  The
history is deep (LOCKSTEP_DEPTH = 10000 samples, ~10 s of steps at the lock-step
rate) because a reliable KEEP_LAST writer (and reader) drops unacknowledged
samples once its history is full: a reader that lags (the recorder, on a busy
machine) must not lose steps (the depth's measurement: docs/nodes.md).

realtime: the newest sample is the only useful one; BEST_EFFORT, KEEP_LAST 1,
VOLATILE avoids retransmissions and queues in the 1 kHz path.  A sample that is
lost or late is a deadline miss at the bridge (it extrapolates; see the bridge
node); the recorder subscribes best-effort too and may lose samples when the
machine is loaded (``rths bench loop`` measures that loss).  The status topic
stays reliable in both modes: it is how misses are accounted for.
"""

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: History depth of the lock-step loop topics (writers and the recorder's readers).
LOCKSTEP_DEPTH = 10000


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
    """Return the QoS the recorder subscribes with: compatible with the publishers, deep history."""
    if mode == 'lockstep':
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=LOCKSTEP_DEPTH,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)


def run_info_qos() -> QoSProfile:
    """Return the QoS of once-per-run facts (``/rths/run_steps``): reliable, latched."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
