"""Faults of the running graph (issue 8): crashes, foreign publishers, duplicates, delay bursts.

Every test checks the two things that must hold whatever happens: the bridge's
safe stop (the plant ends in the safe state, no output beyond a limit) and the
recording (the bag is readable and keeps every step up to the fault, in order,
without gaps).  Faults are injected deterministically (a SIGKILL after a
logged step, the compensator's output through the test-only fault wrapper
``rths_system_tests.faults``, a foreign publisher),
so no assertion depends on the machine's speed; time bounds are the stated
ones (``Launcher.safe_stop_bound_s``), with hold and ramp counted in steps.
"""

import re
import threading
import time

import numpy as np
import pytest

from rths_system_tests import (
    REPO,
    Drain,
    config_copy,
    graph_env,
    launch_background,
    rths,
    sigkill_mid_run,
    wait_for,
    wait_steps,
)

CONFIG = REPO / 'config'
STOPPED = 3
#: Lock-step command watchdog of these runs [s]: bridge.yaml's 5 s.  (1 s tripped in 2 of 3
#: runs on the 2-core CI VM on 2026-11-27: the loop stalled ~1.5 s within its first 13
#: steps, at start-up, before any node was killed.)
WATCHDOG_S = 5.0


def test_fault_wrapper_drops_duplicates_and_delays_the_chosen_steps():
    """The test-only wrapper (typed and CDR messages); an unknown fault is refused by name."""
    from rths_common import cdr
    from rths_msgs.msg import Command
    from rths_system_tests.faults import FaultyPublisher, check_faults

    class Sink:
        def __init__(self):
            self.steps = []

        def publish(self, msg):
            self.steps.append(FaultyPublisher.step_of(msg))

        def get_subscription_count(self):
            return 7

    for make in (lambda k: Command(step=k), lambda k: cdr.pack_step_arrays(0, k, [0.0])):
        sink = Sink()
        pub = FaultyPublisher(sink, drop_every=3, duplicate_every=4, delay_every=5, delay_ms=1.0)
        t0 = time.monotonic()
        for k in range(11):
            pub.publish(make(k))
        assert sink.steps == [0, 1, 2, 4, 4, 5, 7, 8, 8, 10]
        assert pub.counts == {'dropped': 3, 'duplicated': 2, 'delayed': 2}
        assert time.monotonic() - t0 >= 2e-3
        assert pub.get_subscription_count() == 7          # everything else is the publisher's
    with pytest.raises(ValueError, match='loss_pct'):
        check_faults({'compensator': {'loss_pct': 5}})


def read_bag(bag):
    """Bridge status (step, state, stamp) and measurements (step, applied) of a bag."""
    from rths_common import bagio, topics

    status, meas = [], []
    for topic, _, msg in bagio.read_messages(bag, [topics.STATUS, topics.MEASUREMENT]):
        if topic == topics.STATUS and msg.node == 'bridge':
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            status.append((int(msg.step), int(msg.safety_state), stamp, msg.fault))
        elif topic == topics.MEASUREMENT:
            meas.append((int(msg.step), np.asarray(msg.applied, dtype=float)))
    return status, meas


def check_recording(bag):
    """Return the bag is readable; every loop topic starts at 0, in order, without gaps."""
    from rths_review.review import read_loop, step_check

    loop = read_loop(bag)
    for topic, data in loop['steps'].items():
        check = step_check(data['step'])
        assert check['count'] > 100, (topic, check)
        assert check['first'] == 0 and check['gaps'] == 0 and check['in_order'], (topic, check)
        assert check['duplicates'] == 0, (topic, check)
    return loop


@pytest.mark.parametrize('victim', ['compensator', 'numerical', 'bridge'])
def test_sigkill_mid_run_reaches_the_safe_state_and_keeps_the_bag(tmp_path, victim):
    """SIGKILL of any loop node: the plant ends safe within the stated time; the bag holds."""
    config = config_copy(tmp_path / 'config', bridge={'watchdog_timeout_s': WATCHDOG_S},
                         numerical={'duration_s': 600.0})
    bag = tmp_path / 'bag'
    proc = launch_background(config, bag)
    try:
        out = sigkill_mid_run(proc, bag, victim)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, out[-3000:]
    assert f'node {victim} died (killed by SIGKILL)' in out
    assert f'FAILED: node {victim}' in out
    status, meas = read_bag(bag)
    check_recording(bag)
    if victim == 'bridge':
        # The simulated plant lived in the bridge process: it stopped with it.
        assert 'stopped with it: safe state (nothing moves)' in out, out[-2000:]
        return
    bound = float(re.search(r'waiting up to ([\d.]+) s for the bridge', out).group(1))
    # the stated bound: watchdog + hold + ramp (+2 s), from the bridge's parameters
    assert bound == pytest.approx(WATCHDOG_S + 0.1 + 0.25 + 2.0 + 2.0)
    found = re.search(r'safe state \(safety stop\) ([\d.]+) s after', out)
    assert found, out[-4000:]
    took = float(found.group(1))
    assert took <= 2 * bound     # wall time: the stop timer runs below fs on a loaded machine
    # the bridge's last status says STOPPED, with the watchdog as the reason
    assert status[-1][1] == STOPPED, status[-3:]
    assert 'watchdog' in status[-1][3]
    # hold + ramp, counted in steps (machine-independent): within (0.25 + 2 + 2) s at fs
    tripped = next(s for s, state, _, _ in status if state != 0)
    assert status[-1][0] - tripped <= (0.25 + 2.0 + 2.0) * 1024
    # the ramp ended at the safe position, and no output ever left the stroke
    applied = np.concatenate([a for _, a in meas if a.size])
    assert np.all(np.abs(applied) <= 0.254)
    assert abs(meas[-1][1][0]) < 1e-9 or meas[-1][1].size == 0


class ForeignPublisher:
    """A node named 'intruder' flooding /rths/command with 0.2 m commands for any step.

    ``mode`` 'lockstep' publishes Command messages with forged senders in
    ``header.frame_id``; 'realtime' publishes them with the loop's best-effort QoS.
    """

    def __init__(self, domain_id: int, mode: str = 'lockstep', period_s: float = 0.002):
        import rclpy
        from rclpy.context import Context

        from rths_common import topics
        from rths_common.qos import loop_qos
        from rths_msgs.msg import Command

        self.rclpy, self.Command = rclpy, Command
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node('intruder', context=self.context)
        self.pub = self.node.create_publisher(Command, topics.COMMAND, loop_qos(mode))
        self.period_s = period_s
        self.running = True
        self.sent = 0
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self):
        step = 0
        while self.running:
            # forged senders too: empty with any step, a made-up gid with step 0 (in
            # realtime a step 0 starts the bridge's clock: it must be the compensator's)
            for frame, k in (('', step % 4096), ('01.0f.00.00', 0)):
                msg = self.Command(step=k, command=[0.2])
                msg.header.frame_id = frame
                self.pub.publish(msg)
                self.sent += 1
            step += 1
            time.sleep(self.period_s)

    def close(self):
        self.running = False
        self.thread.join(timeout=5.0)
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)


def test_foreign_publisher_and_duplicate_steps_are_logged_and_ignored(tmp_path):
    """A foreign node on /rths/command and duplicated steps change nothing in the run."""
    duration = 2.0
    config = config_copy(tmp_path / 'config', numerical={'duration_s': duration})
    bag = tmp_path / 'bag'
    intruder = ForeignPublisher(int(graph_env()['ROS_DOMAIN_ID']))
    try:
        proc = rths('launch', '--config', config, '--bag', bag, timeout=240,
                    faults={'compensator': {'duplicate_every': 100}})
    finally:
        intruder.close()
    out = proc.stdout
    assert intruder.sent > 100
    assert 'run finished' in out and 'FAILED' not in out
    assert re.search(r'foreign publisher /intruder \(gid [0-9a-f.]+\) on /rths/command', out)
    assert 'foreign command(s) so far' in out
    n_dup = len(range(100, int(duration * 1024), 100))
    assert len(re.findall(r'command of step \d+ ignored: expected step', out)) == n_dup
    status, meas = read_bag(bag)
    steps = [s for s, _ in meas]
    assert steps == list(range(int(duration * 1024)))   # each step once, in order
    applied = np.concatenate([a for _, a in meas])
    assert not np.any(np.isclose(applied, 0.2))          # no foreign command reached the plant
    assert all(state == 0 for _, state, _, _ in status)


def realtime_config(directory, duration_s=3.0):
    """Return a 256 Hz realtime graph (simulated plant, 50-tap unit FIR)."""
    from rths_bench.bench_loop import write_config

    return write_config(directory, rate_hz=256.0, duration_s=duration_s, taps=50,
                        model='sdof', priority=0, watchdog_steps=40)


def bridge_misses(bag) -> int:
    """Return the bridge's running deadline-miss count at the end of a bag."""
    from rths_common import bagio, topics

    return max(int(m.deadline_misses) for _, _, m in bagio.read_messages(bag, [topics.STATUS])
               if m.node == 'bridge')


def test_realtime_delay_bursts_are_deadline_misses_not_faults(tmp_path):
    """Bursts shorter than the watchdog: counted misses, extrapolated, the run completes.

    Processes layout: a command held back in another process while the bridge
    ticks on (composed, the delay would stall the bridge's clock with it: a
    stall, test_stall.py).
    """
    every, burst_ms = 150, 60.0       # 60 ms at 256 Hz: >= 15 ticks pass; watchdog at 40
    config = realtime_config(tmp_path / 'config')
    bag = tmp_path / 'bag'
    proc = rths('launch', '--config', config, '--bag', bag, '--layout', 'processes',
                '--timeout', 180, timeout=300,
                faults={'compensator': {'delay_every': every, 'delay_ms': burst_ms}})
    assert 'run finished' in proc.stdout and 'FAILED' not in proc.stdout
    status, meas = read_bag(bag)
    n_bursts = len(range(every, 768, every))
    assert bridge_misses(bag) >= n_bursts * 15
    assert all(state == 0 for _, state, _, _ in status)  # extrapolation covered every burst
    applied = np.concatenate([a for _, a in meas if a.size])
    assert np.all(np.abs(applied) <= 0.254)
    steps = [s for s, _ in meas]
    assert steps == list(range(len(steps))) and len(steps) >= 768


def test_realtime_foreign_publisher_is_ignored(tmp_path):
    """Realtime (lean CDR): a foreign writer's commands never reach the plant, even step 0.

    The intruder publishes 0.2 m for steps 0, 1, 2, ... and for step 0 again and
    again at about the loop rate, from before the loop starts: without the
    sender check its step 0 starts the bridge's clock with a 0.2 m command (a
    jump: a velocity trip) before the compensator has sent anything.
    """
    config = realtime_config(tmp_path / 'config')
    bag = tmp_path / 'bag'
    intruder = ForeignPublisher(int(graph_env()['ROS_DOMAIN_ID']), mode='realtime',
                                period_s=1.0 / 256)
    try:
        proc = rths('launch', '--config', config, '--bag', bag, '--timeout', 180, timeout=300,
                    check=False)
    finally:
        intruder.close()
    out = proc.stdout
    assert intruder.sent > 100
    assert proc.returncode == 0 and 'run finished' in out, out[-3000:]
    assert re.search(r'foreign publisher /intruder \(gid [0-9a-f.]+\) on /rths/command', out)
    assert 'foreign command(s) so far' in out
    status, meas = read_bag(bag)
    assert all(state == 0 for _, state, _, _ in status), status[-3:]
    applied = np.concatenate([a for _, a in meas if a.size])
    assert not np.any(np.isclose(applied, 0.2))          # no foreign command reached the plant
    steps = [s for s, _ in meas]
    assert steps == list(range(len(steps))) and len(steps) >= 768


def test_realtime_long_delay_burst_trips_the_watchdog_into_the_safe_state(tmp_path):
    """A burst longer than watchdog_steps: hold, ramp, STOPPED; the bag keeps every step."""
    config = realtime_config(tmp_path / 'config', duration_s=8.0)
    bag = tmp_path / 'bag'
    proc = rths('launch', '--config', config, '--bag', bag, '--timeout', 180, timeout=300,
                check=False, faults={'compensator': {'delay_every': 300, 'delay_ms': 1000.0}})
    out = proc.stdout
    assert proc.returncode == 1, out[-3000:]
    assert 'node bridge died (exit code 3: safety stop)' in out
    status, meas = read_bag(bag)
    assert status[-1][1] == STOPPED and 'watchdog' in status[-1][3], status[-3:]
    applied = np.concatenate([a for _, a in meas if a.size])
    assert np.all(np.abs(applied) <= 0.254)
    assert abs(applied[-1]) < 1e-9                     # ramped to the safe position
    steps = [s for s, _ in meas]
    assert steps == list(range(len(steps)))


def send_emergency_stop(domain_id: int, how: str, reason: str) -> str:
    """Stop the bridge by the /rths/emergency_stop topic or service; return its answer."""
    import rclpy
    from rclpy.context import Context
    from std_msgs.msg import String

    from rths_common import topics
    from rths_msgs.srv import EmergencyStop

    context = Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node('operator', context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        if how == 'topic':
            pub = node.create_publisher(String, topics.EMERGENCY_STOP, 10)
            t_end = time.monotonic() + 20.0
            while pub.get_subscription_count() < 1 and time.monotonic() < t_end:
                executor.spin_once(timeout_sec=0.05)
            pub.publish(String(data=reason))
            executor.spin_once(timeout_sec=0.5)   # let the reliable writer deliver it
            return 'published'
        client = node.create_client(EmergencyStop, topics.EMERGENCY_STOP_SERVICE)
        assert client.wait_for_service(timeout_sec=20.0), 'no emergency-stop service'
        future = client.call_async(EmergencyStop.Request(reason=reason))
        executor.spin_until_future_complete(future, timeout_sec=20.0)
        response = future.result()
        assert response is not None and response.accepted, response
        return response.message
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)


@pytest.mark.parametrize('how', ['topic', 'service'])
def test_emergency_stop_mid_run_holds_ramps_and_stops(tmp_path, how):
    """Issue 4: an operator's emergency stop mid-run brings the loop to STOPPED.

    Issue 4: an operator's emergency stop (topic or service) mid-run: hold, ramp to the
    safe position, STOPPED, exit 3; the reason is in the status; the bag keeps every step.
    """
    config = config_copy(tmp_path / 'config', numerical={'duration_s': 600.0})
    bag = tmp_path / 'bag'
    proc = launch_background(config, bag)
    reason = f'operator pressed stop ({how})'
    try:
        drain = Drain(proc, wait_for(proc, 'graph connected'))
        wait_steps(bag, 1024, drain=drain)
        answer = send_emergency_stop(int(graph_env()['ROS_DOMAIN_ID']), how, reason)
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    out = drain.text()
    if how == 'service':
        assert answer == 'holding, then ramping to the safe position'
    assert proc.returncode == 1, out[-3000:]
    assert 'node bridge died (exit code 3: safety stop)' in out, out[-3000:]
    status, meas = read_bag(bag)
    check_recording(bag)
    assert status[-1][1] == STOPPED and reason in status[-1][3], status[-3:]
    tripped = next(s for s, state, _, _ in status if state != 0)
    assert tripped >= 1024                                   # not before the stop was sent
    assert status[-1][0] - tripped <= (0.25 + 2.0 + 2.0) * 1024   # hold + ramp, in steps
    applied = np.concatenate([a for _, a in meas if a.size])
    assert np.all(np.abs(applied) <= 0.254)
    assert abs(meas[-1][1][0]) < 1e-9                        # ramped to the safe position
