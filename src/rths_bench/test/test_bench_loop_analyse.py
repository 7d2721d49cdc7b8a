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
