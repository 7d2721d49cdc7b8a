"""The distributed-RTHS bench: the delay line it chooses for a link."""


def test_delay_steps_for_the_link_fits_the_round_trip():
    from rths_bench.bench_distributed import ROUND_TRIP_OVERHEAD_MS, delay_steps_for

    for one_way_ms, rate in ((1.0, 512.0), (1.0, 1024.0), (0.0, 1024.0), (2.0, 256.0)):
        d = delay_steps_for(one_way_ms, rate)
        budget_ms = (d + 1) * 1000.0 / rate
        assert budget_ms >= 2 * one_way_ms + ROUND_TRIP_OVERHEAD_MS
        assert d == 0 or d * 1000.0 / rate < 2 * one_way_ms + ROUND_TRIP_OVERHEAD_MS
    assert delay_steps_for(1.0, 512.0) == 2   # docs/bench/absorb_delay_512hz.json
