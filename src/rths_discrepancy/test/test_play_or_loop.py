"""Backlash (play) told apart from hysteresis by the data, in the restoring-force scenario.

Two specimens driven by the same displacement path (sines of 3, 5 and 8 mm at 1.5 Hz,
twice over, at 1 kHz; 1 % force and 0.2 % displacement noise), each written here
independently of the workflow's own laws:

* a friction damper with play: a slider behind a clearance of +-0.6 mm carries
  Coulomb friction of 800 N (no force while the clearance is crossed after a reversal);
* a Bouc-Wen loop of another shape than the library's (n = 1.5, beta = 0.6,
  gamma = 0.4), 800 N at saturation.

Both on a frame of 5 kg, 50 N s/m, 20 kN/m.
"""

import numpy as np

from rths_discrepancy import restoring, reversals

FS = 1000.0
SUB = 8
M, C, K = 5.0, 50.0, 2e4


def _path():
    n = int(round(FS / 1.5))
    t = np.arange(2 * n) / FS
    return np.concatenate([a * np.sin(2 * np.pi * 1.5 * t) for a in (3e-3, 5e-3, 8e-3) * 2])


def _fine(x):
    return np.interp(np.arange(x.size * SUB) / SUB, np.arange(x.size), x)


def _friction_with_play(x, gap=0.6e-3, fc=800.0):
    z, zs = x[0], np.empty(x.size)
    for i, xi in enumerate(x):
        z = min(max(z, xi - gap), xi + gap)
        zs[i] = z
    dz = np.gradient(zs)
    return fc * np.tanh(dz / (1e-3 * np.max(np.abs(dz))))


def _bouc_wen_other_shape(x, scale=1.5e-3, n=1.5, beta=0.6, gamma=0.4, f_sat=800.0):
    w, ws = 0.0, np.zeros(x.size)
    for i in range(1, x.size):
        dx = x[i] - x[i - 1]
        w += dx * (1 - abs(w / scale) ** n * (beta + gamma * np.sign(dx * w)))
        ws[i] = w
    return f_sat * ws / (scale * (beta + gamma) ** (-1 / n))


def _record(law, seed=0):
    x = _path()
    f_nl = law(_fine(x))[::SUB]
    v = np.gradient(x) * FS
    f = M * np.gradient(v) * FS + C * v + K * x + f_nl
    rng = np.random.default_rng(seed)
    return restoring.validate({
        'time_s': np.arange(x.size) / FS,
        'displacement_m': x + 0.002 * np.std(x) * rng.standard_normal(x.size),
        'force_N': f + 0.01 * np.std(f) * rng.standard_normal(x.size)}), f_nl


def test_reversal_evidence_reads_play_and_a_smooth_loop():
    x = _path()
    play = reversals.evidence(x, _friction_with_play(_fine(x))[::SUB])
    assert play['play'] and play['plateau_fraction'] > 0.8
    assert abs(play['growth']) < 0.2                        # the width is the clearance
    assert 1.0e-3 < play['plateau_width_median'] < 1.4e-3   # 2 x 0.6 mm
    loop = reversals.evidence(x, _bouc_wen_other_shape(_fine(x))[::SUB])
    assert not loop['play'] and loop['plateau_fraction'] < 0.35
    assert reversals.turning_points(x, 1e-3).size == 2 * 12     # two per cycle


def test_play_is_read_about_the_forces_own_centre():
    # a constant as large as twice the friction (a load cell's zero, a spring's force at
    # a displaced centre) in the force read: before, every half-cycle crossed q = 0 at a
    # point and the reading was "a smooth loop" (plateau fraction 0.0)
    x = _path()
    f = _friction_with_play(_fine(x))[::SUB]
    for const in (1600.0, -1600.0):
        play = reversals.evidence(x, f + const)
        assert play['play'] and play['plateau_fraction'] > 0.8
        assert 1.0e-3 < play['plateau_width_median'] < 1.4e-3
        assert abs(reversals.centre(x, f + const) - const) < 0.05 * 800.0
    loop = reversals.evidence(x, _bouc_wen_other_shape(_fine(x))[::SUB] + 1600.0)
    assert not loop['play'] and loop['plateau_fraction'] < 0.35


def test_reversals_inside_the_clearance_are_not_read():
    # the path above, then 40 small cycles of 0.5 mm, inside the clearance of +-0.6 mm:
    # they never engage, and the force left after them is the 1 % noise.  Noise spikes
    # passed the half-cycle's test (a positive level, a sample past ENGAGED of it) and
    # their near-zero widths, small at small amplitudes, read as a width growing with
    # the amplitude: not play (growth 0.65 on a 3300 Hz sweep with play, whose held-out
    # end turns within the clearance)
    x = _path()
    t = np.arange(40 * 100) / FS
    x = np.concatenate([x, 0.5e-3 * np.sin(2 * np.pi * 10.0 * t)])
    f = _friction_with_play(_fine(x))[::SUB]
    f = f + 0.01 * 800.0 * np.random.default_rng(3).standard_normal(x.size)
    play = reversals.evidence(x, f)
    assert play['play'] and play['plateau_fraction'] > 0.8
    assert play['amplitude_range'][0] > 2e-3             # only the engaging cycles read
    assert abs(play['growth']) < 0.2
    assert 1.0e-3 < play['plateau_width_median'] < 1.4e-3


def test_friction_damper_with_play_is_backlash_and_a_bouc_wen_loop_is_hysteresis():
    data, _ = _record(_friction_with_play)
    res = restoring.run(data, plots=False)
    names = res['effect'].split('+')
    assert 'backlash' in names and 'hysteresis' not in names and len(names) <= 2
    assert res['parameters']['backlash']['b'] == np.clip(res['parameters']['backlash']['b'],
                                                         0.45e-3, 0.75e-3)
    assert res['gap_closed'] > 0.5 and res['play_or_loop']['play']
    data, _ = _record(_bouc_wen_other_shape)
    res = restoring.run(data, plots=False)
    names = res['effect'].split('+')
    assert 'hysteresis' in names and 'backlash' not in names and len(names) <= 2
    assert not res['play_or_loop']['play']


def test_a_hysteresis_answer_on_a_record_with_play_becomes_backlash():
    data, _ = _record(_friction_with_play)
    fit = restoring.Fit(data)
    cands = {restoring.label(n): restoring.fit_candidate(fit, n, 0.0)
             for n in (['coulomb_friction', 'hysteresis'], ['coulomb_friction', 'backlash'])}
    ics = {k: 0.0 for k in cands}
    choice, ev = restoring._play_or_loop(fit, cands, 'coulomb_friction+hysteresis', ics, 1.0)
    assert choice == 'coulomb_friction+backlash' and ev['play']
    assert ev['replaced'] == {'coulomb_friction+hysteresis': 'coulomb_friction+backlash'}
