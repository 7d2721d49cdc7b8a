"""Compensator schemes: the registry from a scheme's name to how it is designed.

Each entry names its design function (the function, or ``module:function`` to import it
on first use; called as
``function(plant, fs_hz=None, **options)`` and returning a
:class:`rths_compensator.design.Design`), the options of ``rths design`` it takes,
and whether ``rths design --auto`` searches it.  The parameters file's ``scheme``
(validated here, :mod:`.params`), ``rths design --scheme`` and the docs tables take
their names from :data:`SCHEMES`; docs/extending.md adds a scheme.

The design modules are imported when a design is asked for, not with this
registry: they pull SciPy's signal and optimize packages (about 1 s), which the
compensator node, that only validates the name, never needs.
"""

import importlib
from typing import Any, NamedTuple

from rths_common.registry import Registry

#: Options every FIR scheme takes (``rths design --taps --fc --epsilon --zero-tol``).
FIR_OPTIONS = ('n_taps', 'fc_hz', 'epsilon', 'zero_tol')
#: The least-squares FIR schemes also weigh the compensator's own gain (``--gain-weight``).
LS_OPTIONS = FIR_OPTIONS + ('gain_weight',)


class Scheme(NamedTuple):
    """One compensator scheme: its design function and the options it takes."""

    summary: str
    designer: Any = ''          # the function, or 'module:function'; '' = not designed
    options: tuple = ()         # option names the design function takes
    fir: bool = False           # an FIR (eq. 28): --auto searches its n and fc
    auto: bool = False          # one of the candidates of rths design --auto

    def design_function(self):
        """Return the design function (a ``module:function`` path: imports its module)."""
        if callable(self.designer):
            return self.designer
        module, _, name = self.designer.partition(':')
        return getattr(importlib.import_module(module), name)


#: Scheme name -> entry (the allowed values of the compensator's ``scheme``).
SCHEMES = Registry('compensator scheme', 'scheme', {
    'ls': Scheme('FIR by least squares (eq. 28-31)', 'rths_compensator.design:design_ls',
                 LS_OPTIONS, fir=True, auto=True),
    'wls': Scheme('FIR by weighted least squares (eq. 32; the seed\'s choice)',
                  'rths_compensator.design:design_wls', LS_OPTIONS, fir=True, auto=True),
    'mm': Scheme('FIR by minimax, a linear programme (eq. 33-36)',
                 'rths_compensator.design:design_mm', FIR_OPTIONS, fir=True, auto=True),
    'inverse': Scheme('inverse compensation of a pure delay (eq. 1-2)',
                      'rths_compensator.design:design_inverse_for', ('delay_ms', 'band_hz')),
    'mff': Scheme('model-based feed-forward from the Table 1 poles (eq. 4)',
                  'rths_compensator.design:design_mff_for', ('alpha', 'poles')),
    'npz': Scheme('NPZ-Ignore (eq. 8)', 'rths_compensator.design:design_npz', auto=True),
    'zpetc': Scheme('modified causal ZPETC (eq. 12)', 'rths_compensator.design:design_zpetc',
                    auto=True),
    'zmetc': Scheme('ZMETC (eq. 14)', 'rths_compensator.design:design_zmetc', auto=True),
    'identity': Scheme('no compensation, G = 1 (rths run --no-compensation)'),
})

#: The scheme of seed section 6.1 (rths run's default).
DEFAULT_SCHEME = 'wls'
#: The scheme a coupled (N x N) FIR is written with: a least-squares fit of P G to a
#: low-pass (``multichannel.design_coupled_fir``).
COUPLED_SCHEME = 'ls'

#: The design defaults of ``rths design`` and ``rths run`` (their one definition): the
#: seed's RTHS compensator (section 6.1: WLS, n = 400, fc = 10 Hz; epsilon, the passband
#: tolerance of eq. 35-36, has no value in the seed) with a small weight on the
#: compensator's own gain above the passband (``design._with_gain_rows``).
DESIGN_DEFAULTS = {'scheme': DEFAULT_SCHEME, 'n_taps': 400, 'fc_hz': 10.0, 'epsilon': 0.002,
                   'gain_weight': 1e-6, 'zero_tol': 1.0}

#: Long dead times at low rates: the lag [s] the FIR must predict (the dead time and the
#: delay of the unstable zeros, :func:`.design.predicted_lag_s`) from which, at rates up to
#: ``LOW_RATE_HZ``, the default fc is raised to ``LONG_DEAD_TIME_FC_HZ``.  The FIR predicts
#: the plant's delay over the passband; beyond fc its error ``|T_com - 1|`` rises the faster
#: the longer the delay, so with fc at the top of the motion's band (the seed's 10 Hz for
#: 0-10 Hz) the motion near 10 Hz is tracked badly.  Measured on the true models of ``rths
#: bench identification`` (0-10 Hz band-limited noise, fc 10 -> 12.5 Hz, n = 400): 1024 Hz,
#: 12.5 ms: 0.50-0.61 -> 0.24-0.29 %; 20 ms: 1.19-1.54 -> 0.70-1.01 %; 5 ms: 0.25-0.33 ->
#: 0.19 % (below the threshold: kept at 10 Hz, already within 0.5 %); at higher rates the
#: 400 taps span less time and 12.5 Hz gains little or loses: 2000 Hz, 12.5 ms 0.23-0.27 ->
#: 0.20-0.24 %, 20 ms 0.49-0.63 -> 0.50-0.68 %; 4096 Hz, 12.5 ms 0.168 -> 0.18 %, 20 ms
#: 0.26-0.33 -> 0.34-0.43 %.  The 1+5 Hz sine is unchanged (0.14-0.20 %).  fc = 15 Hz
#: tracks like 12.5 but raises the command's velocity (0.30-0.33 m/s instead of 0.22 on
#: two 12.5-20 ms actuators); 20 Hz is worse at 20 ms.  The project's own 3-pole plant
#: (dead time 0) keeps the seed's 10 Hz.
LONG_DEAD_TIME_S = 0.0075
LOW_RATE_HZ = 1500.0
LONG_DEAD_TIME_FC_HZ = 12.5


def default_fc_hz(dead_time_s: float, fs_hz: float) -> float:
    """Return the default FIR cut-off [Hz] for a plant whose FIR predicts this lag [s]."""
    if dead_time_s >= LONG_DEAD_TIME_S and fs_hz <= LOW_RATE_HZ:
        return LONG_DEAD_TIME_FC_HZ
    return DESIGN_DEFAULTS['fc_hz']


def designed() -> tuple:
    """Return the names of the schemes ``rths design --scheme`` can design."""
    return tuple(name for name, s in SCHEMES.items() if s.designer)


def fir_schemes() -> tuple:
    """Return the names of the FIR schemes (eq. 28)."""
    return tuple(name for name, s in SCHEMES.items() if s.fir)


def auto_schemes() -> tuple:
    """Return the names of the schemes ``rths design --auto`` compares."""
    return tuple(name for name, s in SCHEMES.items() if s.auto)
