"""Review helpers: step bookkeeping and the delay estimate."""

import numpy as np
import pytest

from rths_review.tracking import step_check, weighted_delay_ms


def test_step_check_counts_gaps_duplicates_and_order():
    assert step_check([0, 1, 2, 3]) == {'count': 4, 'first': 0, 'last': 3, 'gaps': 0,
                                        'duplicates': 0, 'in_order': True}
    c = step_check([0, 1, 3, 3, 2])
    assert (c['gaps'], c['duplicates'], c['in_order']) == (0, 1, False)
    c = step_check([0, 1, 5])
    assert (c['gaps'], c['in_order']) == (3, True)


def test_weighted_delay_recovers_a_pure_delay():
    fs = 1024.0
    rng = np.random.default_rng(0)
    t = np.arange(int(30 * fs)) / fs
    # narrow-band like a building response (2.7 Hz) plus broadband noise
    x = np.sin(2 * np.pi * 2.7 * t) + 0.3 * rng.standard_normal(t.size)
    lag = 14  # samples: 13.67 ms
    y = np.r_[np.zeros(lag), x[:-lag]]
    assert abs(weighted_delay_ms(x, y, fs) - 1e3 * lag / fs) < 0.05
    assert abs(weighted_delay_ms(x, x, fs)) < 1e-4     # the estimate's ridge: < 0.1 us


def test_weighted_delay_is_the_plants_own_on_a_narrow_band_run():
    """Check the weighted delay on a building-like response through a delayed actuator.

    A 1.5 Hz response under an earthquake's envelope through a 3-pole actuator with a 5 ms
    transport delay: the weighted delay equals the plant's own phase delay weighted the
    same way (19.89 ms); the Welch H1 estimate used before read 20.10 ms.
    """
    from scipy import signal

    from rths_compensator.plants import actuator_poles
    from rths_compensator.synthetic import SyntheticActuator
    fs = 1024.0
    plant = SyntheticActuator(actuator_poles('3pole'), 0.005, fs).model()
    n = int(40 * fs)
    t = np.arange(n) / fs
    b, a = signal.iirpeak(1.5, 3, fs=fs)
    x = signal.lfilter(b, a, np.random.default_rng(1).standard_normal(n))
    x *= np.exp(-((t - 12) / 8) ** 2)
    y = plant.simulate(x)
    f, pxx = signal.welch(x, fs=fs, nperseg=4096)
    sel = (f > 0) & (f <= 10)
    _, h = signal.freqz(plant.num, plant.a, worN=f[sel], fs=fs)
    tau = -np.unwrap(np.angle(h)) / (2 * np.pi * f[sel])
    own = 1e3 * np.sum(tau * pxx[sel]) / np.sum(pxx[sel])
    assert weighted_delay_ms(x, y, fs) == pytest.approx(own, abs=0.01)


def test_review_of_a_site_bag_has_table_5_and_no_guessed_model(tmp_path):
    """A bag of rths site (the model ran in the client): table 5, plots, report; no 6-9."""
    from pathlib import Path

    from rths_actuator_bridge import openfresco as of
    from rths_actuator_bridge.site import build_site, load_site_config
    from rths_review.review import review_rths

    config = load_site_config(None, Path(__file__).resolve().parents[3] / 'config')
    core = build_site(config, tmp_path / 'bag')
    sizes = of.Sizes.generic_client(1)
    core.accept(sizes)
    fs = core.fs_hz
    for k in range(int(3 * fs)):   # 3 s of a 2.7 Hz trial under a Hann window
        x = 1e-3 * (1 - np.cos(2 * np.pi * k / (3 * fs))) * np.sin(2 * np.pi * 2.7 * k / fs)
        core.handle(of.decode(of.encode_request(sizes, of.SET_TRIAL_RESPONSE, [x], [0], [0],
                                                k / fs), sizes))
        if k:   # step 0 is the structure at rest, sent before the first analysis step
            core.handle(of.decode(of.encode_request(sizes, of.COMMIT_STATE), sizes))
    core.finish()
    core.recorder.event('client test said goodbye')
    core.recorder.close()
    summary = review_rths(tmp_path / 'bag', tmp_path / 'review')
    assert summary['kind'] == 'site' and summary['steps'] == int(3 * fs)
    assert summary['backend'] == 'simulated' and summary['mode'] == 'pseudodynamic'
    # the designed compensator of config/ removes most of the 3-pole actuator's delay
    assert summary['delay_ms_before'] > 5.0 and abs(summary['delay_ms_after']) < 2.0
    assert summary['site_events'] == ['client test said goodbye']
    text = (tmp_path / 'review' / 'review.txt').read_text()
    assert 'Tables 6-9 need the numerical model' in text
    assert (tmp_path / 'review' / 'report.html').is_file()
    assert (tmp_path / 'review' / 'tracking_zoom.png').is_file()
    assert not (tmp_path / 'review' / 'time_history.png').exists()
