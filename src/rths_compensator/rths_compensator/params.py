"""The compensator parameters file: a ROS 2 parameters YAML read by the compensator node.

Layout (``G(z^-1) = (b0 + b1 z^-1 + ...)/(a0 + a1 z^-1 + ...)``, see :mod:`.filters`)::

    compensator:
      ros__parameters:
        scheme: wls            # ls, wls, mm, inverse, mff, npz, zpetc, zmetc, identity
        fs_hz: 1024.0
        taps: [ ... ]          # b0..bn, always written as doubles ('.' or 'e')
        denominator: [1.0]     # a0..am; [1.0] for a pure FIR
        plant: plant.yaml      # provenance: scalars or strings only
        n_taps: 100
        ...

Both :func:`load_compensator_params` and :func:`write_compensator_params` validate the
content: non-empty finite taps, finite denominator with a0 != 0 and all poles strictly
inside the unit circle (a stable filter), fs_hz > 0, a known scheme.
"""

import datetime
import os

import numpy as np
import yaml

from rths_common.files import atomic_open

SCHEMES = ('ls', 'wls', 'mm', 'inverse', 'mff', 'npz', 'zpetc', 'zmetc', 'identity')


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
                         f'{", ".join(SCHEMES)}')
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

    ``taps`` and ``denominator`` are returned as lists of floats, ``fs_hz`` as float.
    Raises ValueError (naming file, field and fix) or OSError for a missing file.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise OSError(f'{path}: compensator parameters file not found; create it with '
                      "'rths design' or use identity_params()")
    with open(path, encoding='utf-8') as handle:
        try:
            doc = yaml.safe_load(handle)
        except yaml.YAMLError as err:
            raise ValueError(f'{path}: not valid YAML ({err})') from None
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
    params['taps'] = b.tolist()
    params['denominator'] = a.tolist()
    params['fs_hz'] = fs
    return params


def write_compensator_params(path, taps, denominator, fs_hz, scheme, provenance=None) -> str:
    """Validate and atomically write a compensator parameters file; return its path.

    ``provenance`` maps names to scalars/strings (plant, n_taps, fc_hz, epsilon,
    predicted_delay_ms, ...); ``created`` (ISO time, UTC) is added if absent.
    Nothing is written if validation fails.
    """
    path = os.fspath(path)
    b, a, fs = _check(path, taps, denominator, fs_hz, scheme)
    params = {'scheme': str(scheme), 'fs_hz': fs,
              'taps': [float(v) for v in b], 'denominator': [float(v) for v in a]}
    prov = dict(provenance or {})
    prov.setdefault('created', datetime.datetime.now(datetime.timezone.utc).isoformat(
        timespec='seconds'))
    for key, value in prov.items():
        if key in params:
            raise ValueError(f'provenance key {key!r} clashes with a filter field')
        if isinstance(value, (float, np.floating)) and not np.isfinite(value):
            value = str(value)
        params[str(key)] = _scalar(value)
    text = yaml.safe_dump({'compensator': {'ros__parameters': params}},
                          default_flow_style=None, sort_keys=False, width=100)
    with atomic_open(path) as handle:
        handle.write(text)
    return path


def identity_params(fs_hz: float = 1024.0) -> dict:
    """Parameters of the identity compensator (G = 1), same layout as the loaded file."""
    b, a, fs = _check('identity_params', [1.0], [1.0], fs_hz, 'identity')
    return {'scheme': 'identity', 'fs_hz': fs, 'taps': b.tolist(), 'denominator': a.tolist()}
