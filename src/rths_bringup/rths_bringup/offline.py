"""The RTHS loop without ROS, from the nodes' parameters: the same cores, in the same order.

:func:`offline_rths` builds the three cores the nodes build from their
params files (:class:`rths_numerical.stepping.NumericalCore`,
:class:`rths_compensator.core.CompensatorCore`,
:class:`rths_actuator_bridge.bridge.Bridge`) and steps them through
:func:`rths_common.replay.closed_loop`, the order of the lock-step graph::

    command_k      = compensator.step(k, interface_displacement_k)   (an adaptive method
                     also gets measurement_{k-1})
    measurement_k  = bridge.step(k, command_{k-D})   (D = command_delay_steps)
    interface_displacement_{k+1} = numerical.step(k, force_k)

so a lock-step run of the node graph with a simulated plant reproduces it
bit for bit (``test_lockstep_equivalence``).  Anyone can run a coupled
simulation with it, without ROS.
"""

from rths_common.params import core_params
from rths_common.replay import closed_loop
from rths_compensator.core import CompensatorCore
from rths_compensator.params import check_sampling_rate
from rths_numerical.stepping import NumericalCore


def offline_rths(numerical: dict, compensator: dict, bridge: dict) -> dict:
    """Run the coupled loop for every step of the substructure; return per-step arrays."""
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_actuator_bridge.bridge import Bridge

    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_numerical.substructure import make_substructure

    sub = make_substructure(core_params(numerical))
    if 'fs_hz' in compensator:
        check_sampling_rate(compensator, 1.0 / sub.dt, 'compensator', 'the loop rate 1/dt')
    comp = CompensatorCore(dict(compensator, denominator=compensator.get('denominator', [1.0])))
    lab = Bridge()
    lab.configure(core_params(bridge))
    lab.activate()
    try:
        out = closed_loop(NumericalCore(sub), comp, lab, sub.n_steps)
    finally:
        lab.close()
    out['history'] = sub.history()
    return out
