"""Compensation methods: the registry from a method's name to the class that runs it.

``method`` of the compensator parameters chooses how the designed filter runs:
``fir`` as designed, an adaptive method started from it (:mod:`.adaptive`,
docs/adaptive.md), or ``pi_lead``, the RTHS benchmark's reference feedback controller
(:mod:`.feedback`; the designed filter is its fallback).  Each entry names its class
(the class, or ``module:Class`` to import it on first use; built by
``Class.from_design(design, plant, guards, **options)``), whether it adapts (and needs
the identified plant) and whether it is a feedback controller.  The parameters' allowed
values, ``rths run --adaptive`` and the docs tables take their names from
:data:`METHODS`; docs/extending.md adds one.

The classes are imported when a method is built, not with this registry: they pull
SciPy's signal package (about 1 s), which the compensator node running a fixed FIR
never needs.
"""

import importlib
from typing import Any, NamedTuple

from rths_common.registry import Registry


class Method(NamedTuple):
    """One compensation method: its class and what it needs."""

    summary: str
    runner: Any                  # the class, or 'module:Class'; it has a from_design classmethod
    adaptive: bool = True        # adapts on line (needs the plant and the measurement)
    feedback: bool = False       # a feedback controller on the measured displacement

    def method_class(self):
        """Return the class that runs the method (a ``module:Class`` path: imports its module)."""
        if not isinstance(self.runner, str):
            return self.runner
        module, _, name = self.runner.partition(':')
        return getattr(importlib.import_module(module), name)


#: Method name -> entry (the allowed values of the compensator's ``method``).
METHODS = Registry('compensation method', 'method', {
    'fir': Method('the designed filter, fixed', 'rths_compensator.adaptive:FixedFir',
                  adaptive=False),
    'rls_fir': Method('the FIR taps re-estimated by recursive least squares',
                      'rths_compensator.adaptive:RlsFir'),
    'ats': Method('adaptive time series (Chae et al. 2013)', 'rths_compensator.adaptive:Ats'),
    'amb': Method('adaptive model-based (Fermandois and Spencer)',
                  'rths_compensator.adaptive:Amb'),
    'pi_lead': Method('PI tracking controller with phase lead on the measured displacement '
                      '(the RTHS benchmark\'s reference, Silva et al. 2020)',
                      'rths_compensator.feedback:PiLead', adaptive=False, feedback=True),
})


#: The method of a parameters file that names none.
DEFAULT = 'fir'


def method_of(params: dict, where: str = 'compensator parameters') -> Method:
    """Return the entry of ``params['method']`` (default: the fixed designed filter)."""
    return METHODS.entry(str(params.get('method') or DEFAULT), where)


def uses_measurement(entry: Method) -> bool:
    """Tell whether a method needs the measured displacement of the previous step."""
    return entry.adaptive or entry.feedback


def compensator_names() -> tuple:
    """Return the names of the feed-forward methods (the designed filter and its adaptations)."""
    return tuple(name for name, m in METHODS.items() if not m.feedback)


def adaptive_names() -> tuple:
    """Return the names of the adaptive methods."""
    return tuple(name for name, m in METHODS.items() if m.adaptive)
