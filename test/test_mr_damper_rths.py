"""RTHS of the building with the simulated MR-damper specimen (rths run --specimen mr), offline.

The same cores as the lock-step graph (rths_bringup.offline): the repo's designed compensator,
the 3-pole actuator carrying an MR damper (Spencer et al. 1997 model, 1 V) between the 2nd
floor and the ground, five dampers (force scale 5), Kobe x 0.135.  The reference is the
whole-numerical simulation with the same MR model (rths_numerical.mr_damper).
"""

from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def test_mr_damper_rths_matches_the_nonlinear_reference():
    """Issue 16 target: MR-damper RTHS vs reference <= 3 %.

    Measured 0.11 % over 10 s (12.1 % without compensation).  The dampers also
    change the response: >= 10 % RMS reduction.
    """
    from rths_bringup.offline import offline_rths
    from rths_common import runinfo
    from rths_common.params import core_params
    from rths_numerical.mr_damper import simulate_mr_reference
    from rths_numerical.reference import relative_rms_error, simulate_uncontrolled
    from rths_numerical.substructure import make_substructure

    params = {n: runinfo.load_params(REPO / 'config' / f'{n}.yaml', n)
              for n in ('numerical', 'compensator', 'bridge')}
    numerical = dict(params['numerical'], model='building2story', record='kobe', scale=0.135,
                     force_scale=5.0, interface_frame='relative', specimen_mass_kg=0.0,
                     duration_s=6.0)
    for key in ('sdof_mass_kg', 'sdof_freq_hz', 'sdof_zeta', 'harmonic_freq_hz'):
        numerical.pop(key, None)
    out = offline_rths(numerical, params['compensator'],
                       dict(params['bridge'], dtm='mr', mr_voltage_v=1.0))
    rths = out['history']['output_disp']
    ref = simulate_mr_reference(core_params(numerical), 1.0)['output_disp']
    assert relative_rms_error(rths, ref) <= 3.0
    sub = make_substructure(core_params(numerical))
    unc = simulate_uncontrolled(sub.model, sub.ag, sub.dt)['disp']
    assert np.sqrt(np.mean(ref ** 2)) < 0.9 * np.sqrt(np.mean(unc ** 2))
    assert np.max(np.abs(out['force'])) > 200.0
