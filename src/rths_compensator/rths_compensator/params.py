"""The compensator parameters file: a ROS 2 parameters YAML read by the compensator node.

Layout (``G(z^-1) = (b0 + b1 z^-1 + ...)/(a0 + a1 z^-1 + ...)``, see :mod:`.filters`)::

    compensator:
      ros__parameters:
        scheme: wls            # a name of rths_compensator.schemes.SCHEMES
        fs_hz: 1024.0
        taps: [ ... ]          # b0..bn, always written as doubles ('.' or 'e')
        denominator: [1.0]     # a0..am; [1.0] for a pure FIR
        provenance:            # how it was designed: scalars or strings only
          plant: plant.yaml
          n_taps: 100
          ...

The filter fields are :data:`FILTER_PARAMS`; a load feed-forward (the non-linear loads of
an updated actuator model, :mod:`.feedforward`) adds its ``feedforward_*`` keys beside
them.  The provenance has its own key, so
the node rejects every other key (:func:`check_compensator_params`).  Files of an
older ``rths design`` kept the provenance beside the filter fields:
:func:`load_compensator_params` still reads them (their extra keys become the
provenance); the node and ``rths launch`` refuse them with the fix.

Both :func:`load_compensator_params` and :func:`write_compensator_params` validate the
content: non-empty finite taps, finite denominator with a0 != 0 and all poles strictly
inside the unit circle (a stable filter), fs_hz > 0, a known scheme.
"""

import datetime
import os
import textwrap

import numpy as np
import yaml

from rths_common import yamlfile
from rths_common.files import atomic_open
from rths_common.params import LOOP_RATE_RANGE_HZ, node_schema
from rths_common.timebase import format_hz, same_rate

from .feedforward import FEEDFORWARD_PARAMS, feedforward_settings
from .filters import CoupledFir
from .methods import DEFAULT as DEFAULT_METHOD
from .methods import METHODS
from .schemes import SCHEMES

#: The filter fields of a compensator parameters file: key -> (default, meaning [unit]).
FILTER_PARAMS = {
    'scheme': ('identity', 'design scheme (rths_compensator.schemes)'),
    'fs_hz': (1024.0, '[Hz] sampling rate the taps were designed for (= the loop rate)'),
    'taps': ([1.0], '[-] numerator coefficients b0..bn of G(z^-1)'),
    'denominator': ([1.0], '[-] denominator coefficients a0..am ([1.0]: a FIR)'),
}
#: Range of the design rate (inclusive).
FILTER_RANGES = {'fs_hz': LOOP_RATE_RANGE_HZ}
#: The compensator's method key (not a filter field): key -> (default, meaning).
METHOD_PARAMS = {
    'method': (DEFAULT_METHOD, 'the designed filter, an adaptive method started from it '
                               '(needs provenance.plant) or pi_lead (docs/adaptive.md)'),
    'pi_lead_kp': (2.0, '[-] pi_lead: proportional gain (Silva et al. 2020: 2)'),
    'pi_lead_ki': (95.0, '[1/s] pi_lead: integral gain (Silva et al. 2020: 95)'),
    'pi_lead_num': ([50.8316, 8570.4], '[s, -] pi_lead: lead numerator b1, b0 of '
                                       '(b1 s + b0) / (a1 s + a0)'),
    'pi_lead_den': ([1.0, 8570.4], '[s, -] pi_lead: lead denominator a1, a0'),
    'coupled_taps': ([0.0], '[-] fir with several actuators: a coupled N x N FIR instead of '
                            'taps per channel (filters.CoupledFir; entry (i N + l) n + j maps '
                            'target l to command i at lag j); one value: not used'),
}
#: The online stability monitor (rths_compensator.monitor, docs/monitor.md): key ->
#: (default, meaning); the thresholds' defaults are MonitorSettings'.
MONITOR_PARAMS = {
    'monitor': ('off', 'off | warn (publish /rths/stability) | stop (also the safe stop '
                       'through /rths/emergency_stop at a stop threshold)'),
    'monitor_warn_delay_ms': (3.0, '[ms] monitor: tracking delay that warns'),
    'monitor_stop_delay_ms': (5.0, '[ms] monitor: tracking delay that stops'),
    'monitor_warn_error_pct': (25.0, '[%] monitor: relative RMS tracking error that warns'),
    'monitor_stop_error_pct': (50.0, '[%] monitor: relative RMS tracking error that stops'),
}
#: Allowed values of the scheme, the method and the monitor (the registries' names).
CHOICES = {'scheme': SCHEMES.names(), 'method': METHODS.names(),
           'monitor': ('off', 'warn', 'stop')}
#: The key (a mapping) that holds a file's provenance; ROS names its entries provenance.*.
PROVENANCE = 'provenance'


def param_schema(node_params) -> dict:
    """Return the compensator node's parameter schema: its ``node_params`` and the filter's."""
    return node_schema(node_params, {**FILTER_PARAMS, **METHOD_PARAMS, **MONITOR_PARAMS,
                                     **FEEDFORWARD_PARAMS},
                       FILTER_RANGES, CHOICES)


def check_compensator_params(params: dict, where: str) -> None:
    """Refuse keys that are neither filter fields nor provenance (ValueError names the fix).

    ``params`` is a file's ``ros__parameters`` (provenance as a mapping) or a
    node's parameters (provenance as ``provenance.*`` names), node-level keys removed.
    """
    unknown = sorted(k for k in params
                     if k not in FILTER_PARAMS and k not in METHOD_PARAMS
                     and k not in MONITOR_PARAMS and k not in FEEDFORWARD_PARAMS
                     and k != PROVENANCE
                     and not k.startswith(PROVENANCE + '.'))
    if unknown:
        raise ValueError(f'{where}: unknown parameter(s) {", ".join(unknown)}; the compensator '
                         f'takes {", ".join(FILTER_PARAMS)} and {PROVENANCE}.*. A file written '
                         "by an older 'rths design' keeps its provenance beside the filter "
                         f"fields: move those keys under '{PROVENANCE}:' (or design it again)")


#: Filter coefficients (taps + denominator) times the loop rate the compensator may cost:
#: 1e8 multiply-adds per second, a tenth of one core at ~1 ns each with the memory traffic
#: of a long filter (97 656 coefficients at 1024 Hz; the seed's FIR has 400).
MAX_COEFFICIENT_RATE = 1e8


def check_filter_cost(n_coefficients: int, fs_hz: float, where: str) -> None:
    """Refuse a filter the loop cannot compute in its period (ValueError with the bound)."""
    n, fs = int(n_coefficients), float(fs_hz)
    if n * fs > MAX_COEFFICIENT_RATE:
        most = int(MAX_COEFFICIENT_RATE // fs)
        raise ValueError(f'{where}: {n} filter coefficients at {format_hz(fs)} Hz are '
                         f'{n * fs:.3g} multiply-adds per second, more than the loop affords '
                         f'({MAX_COEFFICIENT_RATE:.0e}/s: at most {most} coefficients at '
                         f'{format_hz(fs)} Hz); design fewer taps')


def check_sampling_rate(params: dict, loop_fs_hz: float, where: str, loop_where: str) -> None:
    """Refuse taps designed for another rate than the loop's, or too many for its period.

    (ValueError names the fix.)  A scheme that is not designed (identity, G = 1) holds at
    every rate.
    """
    scheme = SCHEMES.get(params.get('scheme'))
    if scheme is not None and not scheme.designer:
        return
    n = len(np.ravel(params.get('taps', [1.0]))) + len(np.ravel(params.get('denominator', [1.0])))
    check_filter_cost(n, loop_fs_hz, where)
    fs, loop_fs_hz = float(params.get('fs_hz', FILTER_PARAMS['fs_hz'][0])), float(loop_fs_hz)
    if not same_rate(fs, loop_fs_hz):
        fs_s, loop_s = format_hz(fs), format_hz(loop_fs_hz)
        raise ValueError(f'{where}: field fs_hz = {fs_s} Hz: the taps were designed for '
                         f'{fs_s} Hz but the loop runs at {loop_s} Hz '
                         f'({loop_where}); design them for {loop_s} Hz (a plant '
                         f"identified at {loop_s} Hz, then 'rths design --plant PLANT "
                         f"--out compensator.yaml'; 'rths run' does both) or give the "
                         f'compensator a params file designed for {loop_s} Hz, or run '
                         f'the loop at {fs_s} Hz (fs_hz of numerical.yaml and bridge.yaml)')


def _check(where, taps, denominator, fs_hz, scheme):
    """Validate the filter fields; return (taps, denominator, fs_hz) as floats."""
    try:
        b = np.asarray(taps, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f'{where}: field taps must be a list of numbers') from None
    try:
        a = np.asarray(denominator, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f'{where}: field denominator must be a list of numbers') from None
    if b.size == 0:
        raise ValueError(f'{where}: field taps is empty; give the numerator coefficients b0..bn')
    if not np.all(np.isfinite(b)):
        raise ValueError(f'{where}: field taps holds nan/inf; redesign the compensator')
    if a.size == 0 or not np.all(np.isfinite(a)):
        raise ValueError(f'{where}: field denominator must be a non-empty finite list '
                         '(use [1.0] for a FIR)')
    if a[0] == 0.0:
        raise ValueError(f'{where}: field denominator has a0 = 0; the leading coefficient '
                         'must be non-zero')
    if a.size > 1:
        poles = np.roots(a)
        if poles.size and np.max(np.abs(poles)) >= 1.0:
            raise ValueError(f'{where}: field denominator is unstable (largest pole modulus '
                             f'{np.max(np.abs(poles)):.6g} >= 1); redesign the compensator')
    try:
        fs = float(fs_hz)
    except (TypeError, ValueError):
        raise ValueError(f'{where}: field fs_hz must be a number in Hz') from None
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f'{where}: field fs_hz must be > 0 Hz, got {fs_hz!r}')
    if scheme not in SCHEMES:
        raise ValueError(f'{where}: field scheme {scheme!r} is unknown; use one of '
                         f'{SCHEMES.text(", ")}')
    return b, a, fs


def validate_filter(where, taps, denominator, fs_hz, scheme):
    """Public form of the filter validation: return (taps, denominator, fs_hz) or raise.

    ``where`` names the source (file or node) in the ValueError message.
    """
    return _check(where, taps, denominator, fs_hz, scheme)


def _scalar(value):
    """Convert a provenance value to a YAML/ROS-friendly scalar."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if value is None:
        return ''
    return str(value)


def load_compensator_params(path) -> dict:
    """Read and validate a compensator parameters file; return its ``ros__parameters`` dict.

    ``taps`` and ``denominator`` are returned as lists of floats, ``fs_hz`` as float,
    the provenance as the mapping ``params['provenance']`` (also of an older file).
    Raises ValueError (naming file, field and fix) or OSError for a missing file.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise OSError(f'{path}: compensator parameters file not found; create it with '
                      "'rths design' or use identity_params()")
    return compensator_params_from(yamlfile.load(path), path)


def compensator_params_from(doc, path) -> dict:
    """:func:`load_compensator_params` of the file ``path`` already parsed into ``doc``."""
    if not isinstance(doc, dict) or 'compensator' not in doc:
        raise ValueError(f"{path}: top-level key 'compensator' missing; the file must start "
                         "with 'compensator:' then 'ros__parameters:'")
    node = doc['compensator']
    if not isinstance(node, dict) or not isinstance(node.get('ros__parameters'), dict):
        raise ValueError(f"{path}: key 'compensator.ros__parameters' missing or not a mapping")
    params = dict(node['ros__parameters'])
    for field in ('taps', 'fs_hz', 'scheme'):
        if field not in params:
            raise ValueError(f'{path}: field {field} missing under compensator.ros__parameters')
    params.setdefault('denominator', [1.0])
    b, a, fs = _check(path, params['taps'], params['denominator'], params['fs_hz'],
                      params['scheme'])
    provenance = params.pop(PROVENANCE, None) or {}
    if not isinstance(provenance, dict):
        raise ValueError(f'{path}: field {PROVENANCE} must be a mapping of names to values')
    # an older 'rths design' wrote the provenance beside the filter fields
    provenance.update({k: params.pop(k) for k in list(params)
                       if k not in FILTER_PARAMS and k not in METHOD_PARAMS
                       and k not in FEEDFORWARD_PARAMS})
    params.update({k: v for k, v in feedforward_settings(params, path).items() if k in params})
    params.update(taps=b.tolist(), denominator=a.tolist(), fs_hz=fs)
    params[PROVENANCE] = provenance
    return params


def write_compensator_params(path, taps, denominator, fs_hz, scheme, provenance=None,
                             feedforward=None, coupled_taps=None) -> str:
    """Validate and atomically write a compensator parameters file; return its path.

    ``provenance`` maps names to scalars/strings (plant, n_taps, fc_hz, epsilon,
    predicted_delay_ms, ...); ``created`` (ISO time, UTC) is added if absent.
    ``feedforward`` maps keys of :data:`.feedforward.FEEDFORWARD_PARAMS` to values (the
    load feed-forward of an updated actuator model), written beside the filter fields.
    ``coupled_taps`` (N x N x n, several actuators): the coupled FIR the node runs
    instead of ``taps`` (:class:`rths_compensator.filters.CoupledFir`).
    Nothing is written if validation fails.
    """
    path = os.fspath(path)
    b, a, fs = _check(path, taps, denominator, fs_hz, scheme)
    params = {'scheme': str(scheme), 'fs_hz': fs,
              'taps': [float(v) for v in b], 'denominator': [float(v) for v in a]}
    if feedforward:
        unknown = sorted(set(feedforward) - set(FEEDFORWARD_PARAMS))
        if unknown:
            raise ValueError(f'{path}: unknown feed-forward key(s) {", ".join(unknown)}; use '
                             f'{", ".join(FEEDFORWARD_PARAMS)}')
        checked = feedforward_settings(feedforward, path)
        params.update({k: checked[k] for k in feedforward})
    if coupled_taps is not None:
        params['coupled_taps'] = [float(v) for v in CoupledFir(coupled_taps).taps.ravel()]
    prov = dict(provenance or {})
    prov.setdefault('created', datetime.datetime.now(datetime.timezone.utc).isoformat(
        timespec='seconds'))
    params[PROVENANCE] = {}
    for key, value in prov.items():
        if isinstance(value, (float, np.floating)) and not np.isfinite(value):
            value = str(value)
        params[PROVENANCE][str(key)] = _scalar(value)
    provenance = params.pop(PROVENANCE)
    text = yaml.safe_dump({'compensator': {'ros__parameters': params}},
                          default_flow_style=None, sort_keys=False, width=100)
    text += textwrap.indent(yaml.safe_dump({PROVENANCE: provenance}, default_flow_style=False,
                                           sort_keys=False, width=100), '    ')
    with atomic_open(path) as handle:
        handle.write(text)
    return path


def identity_params(fs_hz: float = 1024.0) -> dict:
    """Return the identity compensator's parameters (G = 1), in the loaded file's layout."""
    b, a, fs = _check('identity_params', [1.0], [1.0], fs_hz, 'identity')
    return {'scheme': 'identity', 'fs_hz': fs, 'taps': b.tolist(), 'denominator': a.tolist(),
            PROVENANCE: {}}


def coupled_taps_of(params: dict, where: str = 'compensator parameters'):
    """Return the coupled FIR's flat taps (``coupled_taps``), or None when it is not used.

    Used when it holds more than one value; refused (ValueError naming the fix) when a value
    is not finite or the method is not the fixed filter ``fir``.
    """
    values = params.get('coupled_taps')
    if values is None or np.size(values) <= 1:
        return None
    try:
        v = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError(f'{where}: coupled_taps must be a list of numbers') from None
    if not np.all(np.isfinite(v)):
        raise ValueError(f'{where}: coupled_taps holds nan/inf; redesign the compensator')
    method = str(params.get('method') or DEFAULT_METHOD)
    if method != DEFAULT_METHOD:
        raise ValueError(f'{where}: coupled_taps runs as the fixed filter; set method: '
                         f'{DEFAULT_METHOD} (not {method}) or drop coupled_taps')
    return v
