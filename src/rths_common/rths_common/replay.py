"""The RTHS loop without ROS: the three cores stepped through their contract, as the nodes do.

:func:`closed_loop` takes a numerical core, a compensator core and a bridge
(each with ``next_step`` and ``step(k, u) -> StepResult``,
:mod:`rths_common.stepping`) and runs loop step k the way the node graph
does::

    command_k     = compensator.step(k, interface_displacement_k)
    measurement_k = bridge.step(k, command_{k-D})         (D = command_delay_steps)
    interface_displacement_{k+1} = numerical.step(k, force_k)

In lock-step (``lose`` empty) this is the order of the lock-step graph, so a
lock-step run of the nodes with a simulated plant equals it bit for bit
(``rths_bringup.offline.offline_rths`` builds the cores from params files and
calls it).  With ``lose`` it is the realtime loop at zero latency: the
bridge ticks every step whatever arrived, a lost message is never seen by its
reader, and each core's missing-input policy fills the gap (the numerical
and compensator cores interpolate, the bridge extrapolates a missing command).
"""

import numpy as np

from rths_common.stepping import Driver

#: The messages :func:`closed_loop` can lose (the argument ``lose``).
LOSABLE = ('interface_displacement', 'command', 'measurement')


def closed_loop(numerical, compensator, bridge, n_steps: int, lose=None) -> dict:
    """Run up to ``n_steps`` loop steps; return per-step arrays.

    ``numerical`` also has ``first_displacement()`` and ``done()``; ``bridge``
    has ``receive(k, command)``/``due(k)`` (its command delay line); an
    adaptive ``compensator`` (attribute ``adaptive`` True) has
    ``measure(k, displacement, applied)``.  ``lose``: message name (one of
    :data:`LOSABLE`) -> steps whose message is lost.  The loop ends when the
    numerical core is done, or after a step whose measured force is not finite
    (the bridge stopped and wrote nothing: the numerical node would end the
    run there).  Returned: arrays of shape (n_steps, n_interface), NaN where a
    step produced nothing or did not run: ``interface_displacement``,
    ``command``, ``applied``, ``displacement``, ``force``; ``safety_state``
    (after the last step run: its state); ``steps_run``; per core, the inputs
    its policy filled (``filled_numerical``, ``filled_compensator``) and the
    bridge's ticks without a command (``missing_commands``).
    """
    lose = {name: set(steps) for name, steps in (lose or {}).items()}
    unknown = set(lose) - set(LOSABLE)
    if unknown:
        raise ValueError(f'closed_loop: cannot lose {sorted(unknown)}; use {LOSABLE}')
    lockstep = not any(lose.values())
    num, comp = Driver(numerical, lockstep), Driver(compensator, lockstep)
    adaptive = bool(getattr(compensator, 'adaptive', False))
    first = np.asarray(numerical.first_displacement(), dtype=float)
    n_dof = first.size
    out = {name: np.full((n_steps, n_dof), np.nan)
           for name in ('interface_displacement', 'command', 'applied', 'displacement', 'force')}
    state = np.zeros(n_steps, dtype=int)
    counts = {'filled_numerical': 0, 'filled_compensator': 0, 'missing_commands': 0}
    displacement: np.ndarray | None = first
    k = 0
    while k < n_steps and not numerical.done():
        if displacement is not None and k not in lose.get('interface_displacement', ()):
            out['interface_displacement'][k] = displacement
            result = comp.feed(k, displacement)
            counts['filled_compensator'] += result.filled
            if k not in lose.get('command', ()):
                bridge.receive(k, result.output)
                out['command'][k] = result.output
        due = bridge.due(k)   # the command of step k - D, None if it never came
        counts['missing_commands'] += due is None
        measured = bridge.step(k, due)
        out['applied'][k, :measured.applied.size] = measured.applied
        out['displacement'][k] = measured.displacement
        out['force'][k] = measured.force
        state[k] = measured.state
        displacement = None
        if not np.all(np.isfinite(measured.force)):   # the bridge wrote nothing: it stopped
            k += 1
            break                                      # (the numerical node ends the run)
        if k not in lose.get('measurement', ()):
            if adaptive:
                compensator.measure(k, measured.displacement, measured.applied)
            result = num.feed(k, measured.force)
            counts['filled_numerical'] += result.filled
            displacement = result.output
        k += 1
    state[k:] = state[k - 1] if k else 0
    return dict(out, safety_state=state, steps_run=k, **counts)
