"""``rths bench loop``'s figures from the nodes' timing files: the round trip and its parts."""

import numpy as np

from rths_bench.bench_loop import analyse

PERIOD_NS = 976_562           # 1024 Hz
N = 200


def _timing(tmp_path, to_numerical_us, numerical_us, to_bridge_us):
    """Write timing files of a loop whose three parts of the round trip take the given times.

    Tick k is at k periods; the numerical node receives measurement k ``to_numerical_us``
    later, publishes step k + 1 ``numerical_us`` after that, and the bridge receives
    command k + 1 ``to_bridge_us`` after the publish.
    """
    ticks = np.arange(N) * PERIOD_NS
    got = ticks + int(to_numerical_us * 1e3)
    pub = np.concatenate([[0], got[:-1] + int(numerical_us * 1e3)])   # step 0 at start
    recv = pub + int(to_bridge_us * 1e3)
    np.savez(tmp_path / 'bridge.npz', tick_step=np.arange(N), tick_wall_ns=ticks,
             tick_late_ns=np.zeros(N, dtype=np.int64), missed=np.zeros(N, dtype=bool),
             recv_step=np.arange(N), recv_wall_ns=recv, late=0, overruns=0,
             period_ns=PERIOD_NS, n_steps=N)
    np.savez(tmp_path / 'numerical.npz', pub_step=np.arange(N), pub_wall_ns=pub,
             recv_step=np.arange(N), recv_wall_ns=got, misses=0)
    return tmp_path / 'bridge.npz', tmp_path / 'numerical.npz'


def test_the_round_trip_is_split_into_its_three_parts(tmp_path):
    r = analyse(*_timing(tmp_path, 250.0, 120.0, 400.0), rate_hz=1024.0)
    assert r['measurement_us_p50'] == 250.0
    assert r['numerical_us_p50'] == 120.0
    assert r['latency_us_p50'] == 400.0
    assert r['loop_us_p50'] == 770.0            # the three parts add up to the round trip
    assert r['deadline_misses'] == 0 and r['late_or_missed_pct'] == 0.0


def test_a_stall_the_thread_worked_through_is_told_from_one_it_waited_out():
    from rths_bench.bench_loop import stalls_on_cpu

    # ticks every period with 0.4 ms of the thread's CPU each; tick 50 comes 3 ms late with
    # the thread on the CPU all along (its work took that long), tick 120 comes 5 ms late
    # after 0.3 ms of CPU (it waited: preempted, blocked or the vCPU was taken)
    wall = np.arange(N, dtype=np.int64) * PERIOD_NS
    late = np.zeros(N, np.int64)
    cpu_step = np.full(N, 400_000, np.int64)
    for k, late_ns, cpu_ns in ((50, 3_000_000, 3_900_000), (120, 5_000_000, 300_000)):
        wall[k:] += late_ns
        late[k] = late_ns
        cpu_step[k] = cpu_ns
    cpu = np.cumsum(cpu_step)
    r = stalls_on_cpu(wall, late, cpu, PERIOD_NS)
    assert r['loop_stalls'] == 2 and r['loop_stalls_on_cpu'] == 1
    assert r['loop_stall_ms_on_cpu'] == round((PERIOD_NS + 3_000_000) * 1e-6, 1)
    assert r['loop_stall_ms_off_cpu'] == round((PERIOD_NS + 5_000_000) * 1e-6, 1)
    # a tick late by less than a period is no stall
    late[50] = late[120] = PERIOD_NS // 2
    assert stalls_on_cpu(wall, late, cpu, PERIOD_NS)['loop_stalls'] == 0


def test_the_analysis_reads_the_ticking_threads_cpu_time_when_the_bridge_wrote_it(tmp_path):
    bridge, numerical = _timing(tmp_path, 250.0, 120.0, 400.0)
    assert 'loop_stalls_on_cpu' not in analyse(bridge, numerical, rate_hz=1024.0)  # older files
    with np.load(bridge) as old:
        files = dict(old)
    files['tick_cpu_ns'] = np.arange(N, dtype=np.int64) * 400_000
    np.savez(bridge, **files)
    r = analyse(bridge, numerical, rate_hz=1024.0)
    assert r['loop_stalls'] == 0 and r['loop_stalls_on_cpu'] == 0
    assert r['tick_cpu_us_p50'] == r['tick_cpu_us_max'] == 400.0   # the loop's work per tick


def test_the_work_floor_times_the_same_work_each_period_and_reports_its_stretches():
    from rths_bench.bench_loop import work_floor

    w = work_floor(0.05, priority=1)
    assert w['chunks'] == round(0.05 * 1024)
    assert 0 < w['chunk_us_p50'] <= w['chunk_us_p99'] <= w['chunk_us_max']
    assert 0.0 <= w['stretched_pct'] <= 100.0 and 0.0 <= w['stretched_on_cpu_pct'] <= 100.0
