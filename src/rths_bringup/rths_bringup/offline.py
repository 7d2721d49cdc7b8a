"""The RTHS loop without ROS: the same cores, called in the same order as the lock-step nodes.

Each loop step k, exactly as the three nodes do it in lock-step mode:

    command_k      = compensator.step(interface_displacement_k)        (compensator node;
                     an adaptive method also gets measurement_{k-1})
    measurement_k  = bridge.step(k, command_{k-D})   (bridge node; D = command_delay_steps)
    interface_displacement_{k+1} = substructure.advance(force_k)       (numerical node)

so a lock-step run of the node graph with a simulated plant must reproduce
:func:`offline_rths` to floating-point round-off (``test_lockstep_equivalence``).
Anyone can run a coupled simulation with it, without ROS.
"""

import numpy as np

from rths_common.params import core_params


def offline_rths(numerical: dict, compensator: dict, bridge: dict) -> dict:
    """Run the coupled loop for every step of the substructure; return per-step arrays."""
    from rths_actuator_bridge.bridge import Bridge
    from rths_compensator.filters import MultiChannelFilter
    from rths_compensator.params import check_sampling_rate
    from rths_numerical.substructure import make_substructure

    sub = make_substructure(core_params(numerical))
    if 'fs_hz' in compensator:
        check_sampling_rate(compensator, 1.0 / sub.dt, 'compensator', 'the loop rate 1/dt')
    adaptive = str(compensator.get('method', 'fir') or 'fir') != 'fir'
    if adaptive:   # command k waits for measurement k-1, as the lock-step node does
        from rths_compensator.adaptive import methods_from_params
        comp = methods_from_params(compensator, sub.n_interface)
    else:
        comp = MultiChannelFilter(compensator['taps'], compensator.get('denominator', [1.0]),
                                  n_channels=sub.n_interface)
    lab = Bridge()
    lab.configure(core_params(bridge))
    lab.activate()
    n = sub.n_steps
    out = {name: np.full((n, sub.n_interface), np.nan)
           for name in ('interface_displacement', 'command', 'applied', 'displacement', 'force')}
    state = np.zeros(n, dtype=int)
    displacement = sub.first_displacement()
    k = 0
    while not sub.done():
        if adaptive:
            command = comp.step(np.asarray(displacement, dtype=float),
                                out['displacement'][k - 1] if k else None,
                                out['applied'][k - 1] if k else None)
        else:
            command = comp.step(np.asarray(displacement, dtype=float))
        lab.receive(k, command)
        result = lab.step(k, lab.due(k))   # command of step k - D (command_delay_steps)
        out['interface_displacement'][k] = displacement
        out['command'][k] = command
        out['applied'][k, :result.applied.size] = result.applied
        out['displacement'][k] = result.displacement
        out['force'][k] = result.force
        state[k] = result.state
        displacement = sub.advance(np.asarray(result.force, dtype=float))
        k += 1
    lab.close()
    out['safety_state'] = state
    out['history'] = sub.history()
    return out
