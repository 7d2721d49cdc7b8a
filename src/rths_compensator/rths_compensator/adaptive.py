"""Adaptive compensation: the designed FIR and three adaptive methods behind one interface.

Every method maps the target (interface) displacement of step k to the command of step k::

    command_k = method.step(target_k, measured_prev)

where ``measured_prev`` is the measured displacement of step k-1 (None when it is not
available: then nothing adapts).  ``coefficients()`` returns the current coefficients (for
publishing) and ``status`` a :class:`Status` (``fixed``, ``adapting``, ``frozen`` or
``fallback``, and why).

Methods (the registry :data:`.methods.METHODS`; :func:`make_method` builds each from the
identified plant and its designed FIR):

``fir``
    :class:`FixedFir`, the designed compensator ``G = A*/B+* . H`` (:mod:`.design`).
``rls_fir``
    :class:`RlsFir`: the same structure with the taps h of H estimated on line by recursive
    least squares with forgetting on the regression that defines the FIR design: with
    ``w = (A*/B+*) y`` (the measured displacement through the fixed part of G), the design
    asks ``H(w) = u`` (``T G = 1`` on the command u that produced y), so
    ``u_{k-1} = h . [w_{k-1}, ..., w_{k-n}]``; the designed h is the initial estimate.
``ats``
    :class:`Ats`, the adaptive time-series compensator (Chae, Kazemibidokhti & Ricles 2013):
    ``u = a0 x + a1 xd + a2 xdd`` of the target, with a fitted by least squares over a
    sliding window (1 s, every 16th step) on the inverse relation ``u = a0 y + a1 yd + a2
    ydd`` of the (low-passed) measured displacement, started from ``[1, tau, tau^2/2]`` with
    tau the identified plant's delay; bounds and rate limits as in OpenFresco's set-up.
``amb``
    :class:`Amb`, adaptive model-based compensation (Fermandois & Spencer): ``u = theta .
    [x, xd, xdd, xddd]`` of the target (backward differences), theta started from the
    least-squares inverse of the identified plant over the band and adapted by normalised
    gradient on the tracking error, with the regressor filtered through the plant model.

Guards (all adaptive methods, :class:`Guards`): adaptation freezes while the target's
RMS over ``window_s`` is below ``excitation_m`` or a fault is flagged
(:meth:`AdaptiveMethod.flag_fault`); coefficients stay inside stated bounds and move at most
at a stated rate; a non-finite command, coefficient or measurement, or a relative RMS
tracking error over ``window_s`` above ``fallback_pct`` (while excited), switches the method
to the designed FIR for the rest of the run (the FIR runs in parallel, so the switch is
bumpless) and the status says why.
"""

import dataclasses
import math

import numpy as np
from scipy import signal

from .design import Design, plant_polynomials
from .filters import CausalFilter, MultiChannelFilter
from .identification import load_plant
from .indicators import time_delay_ms
from .methods import DEFAULT, METHODS, method_of


@dataclasses.dataclass
class Status:
    """What a method is doing: ``fixed``, ``adapting``, ``frozen`` or ``fallback``, and why."""

    state: str
    reason: str = ''


@dataclasses.dataclass
class Guards:
    """Safety settings shared by the adaptive methods (SI units)."""

    excitation_m: float = 2.54e-4     # target RMS below which adaptation freezes (0.01 in)
    window_s: float = 0.5             # time constant of the RMS monitors
    fallback_pct: float = 30.0        # relative RMS tracking error that triggers the fallback
    grace_s: float = 1.0              # no fallback decision before this much running time


class _Monitor:
    """Exponentially weighted mean squares of the target and the tracking error."""

    def __init__(self, fs_hz, window_s):
        self.alpha = 1.0 / max(1.0, window_s * fs_hz)
        self.ms_target = 0.0
        self.ms_error = 0.0

    def update(self, target, error):
        a = self.alpha
        self.ms_target += a * (target * target - self.ms_target)
        self.ms_error += a * (error * error - self.ms_error)

    def relative_pct(self):
        if self.ms_target <= 0.0:
            return 0.0
        return 100.0 * math.sqrt(self.ms_error / self.ms_target)


class FixedFir:
    """The designed compensator (any causal rational ``taps/denominator``), never adapting."""

    name = 'fir'

    @classmethod
    def options_from_params(cls, params: dict) -> dict:
        """Return the constructor options read from compensator parameters (none)."""
        return {}

    def __init__(self, taps, denominator=(1.0,)):
        self._filter = CausalFilter(taps, denominator)
        self._x = 0.0
        self.status = Status('fixed', 'designed compensator')

    @classmethod
    def from_design(cls, design: Design, plant=None, guards=None, **options):
        """Run ``design`` as it is (the plant, guards and options are not used)."""
        return cls(design.taps, design.denominator)

    def step(self, target, measured_prev=None):
        """Return the command for ``target`` (a non-finite one repeats the last finite one)."""
        if math.isfinite(target):
            self._x = float(target)
        return self._filter.step(self._x)

    def coefficients(self):
        """Return the designed numerator taps."""
        return self._filter.taps.copy()

    def flag_fault(self, reason='fault'):
        """Nothing adapts; accepted for a uniform interface."""

    def clear_fault(self):
        """Nothing adapts; accepted for a uniform interface."""


#: Kinds of a frozen status's reason, worded by :attr:`AdaptiveMethod.status` when asked.
_FAULT, _EXCITATION = 1, 2


class AdaptiveMethod:
    """Shared guard logic; subclasses implement ``_command``, ``_adapt`` and ``coefficients``."""

    name = ''

    @classmethod
    def options_from_params(cls, params: dict) -> dict:
        """Return the constructor options the method reads from compensator parameters."""
        return {}

    @classmethod
    def from_design(cls, design: Design, plant=None, guards: Guards = None, **options):
        """Build the method from the designed FIR and the identified ``plant`` (required)."""
        if plant is None:
            raise ValueError(f'method {cls.name!r} needs the identified plant (plant.yaml)')
        return cls(design, plant, guards, **options)

    def __init__(self, design: Design, guards: Guards = None):
        self.fs_hz = float(design.fs_hz)
        self.dt = 1.0 / self.fs_hz
        self.guards = guards or Guards()
        self._fir = FixedFir(design.taps, design.denominator)
        self._monitor = _Monitor(self.fs_hz, self.guards.window_s)
        self._grace = int(round(self.guards.grace_s * self.fs_hz))
        self._k = 0
        self._fault = ''
        self._fallback = ''
        self._prev_target = None
        self._last_finite = 0.0
        self.status = Status('frozen', 'no measurement yet')

    # ----------------------------------------------------------------- interface
    @property
    def status(self) -> Status:
        """Return what the method is doing, and why (built when asked: a step keeps its parts)."""
        reason = self._reason
        if type(reason) is tuple:
            kind, value = reason
            if kind == _FAULT:
                reason = f'fault flagged: {value}'
            else:
                reason = (f'excitation {math.sqrt(value):.3g} m RMS '
                          f'< {self.guards.excitation_m:g} m')
        return Status(self._state, reason)

    @status.setter
    def status(self, value: Status):
        self._state, self._reason = value.state, value.reason

    def step(self, target, measured_prev=None):
        """Command for ``target`` (step k), adapting on ``measured_prev`` (step k-1)."""
        target = float(target)
        if not math.isfinite(target):
            self._fall_back(f'non-finite target {target}; holding the last finite one')
            target = self._last_finite
        self._last_finite = target
        fir_cmd = self._fir.step(target)
        if self._fallback:
            return fir_cmd
        if measured_prev is not None and self._prev_target is not None:
            self._observe(float(measured_prev))
            if self._fallback:
                return fir_cmd
        command = self._command(target)
        if not math.isfinite(command):
            return self._fall_back(f'non-finite command {command}', fir_cmd)
        self._prev_target = target
        self._k += 1
        return command

    def flag_fault(self, reason='fault'):
        """Freeze adaptation until :meth:`clear_fault` (e.g. the bridge reported a fault)."""
        self._fault = str(reason) or 'fault'

    def clear_fault(self):
        """Allow adaptation again after :meth:`flag_fault`."""
        self._fault = ''

    @property
    def fallen_back(self) -> bool:
        """Return True once the method has switched to the designed FIR."""
        return bool(self._fallback)

    # ----------------------------------------------------------------- guards
    def _observe(self, measured):
        if not math.isfinite(measured):
            self._fall_back(f'non-finite measurement {measured}')
            return
        error = self._prev_target - measured
        mon = self._monitor
        mon.update(self._prev_target, error)
        g = self.guards
        excited = mon.ms_target >= g.excitation_m ** 2
        if excited and self._k > self._grace:
            rel = mon.relative_pct()
            if rel > g.fallback_pct:
                self._fall_back(f'tracking error {rel:.1f} % > {g.fallback_pct:g} %')
                return
        # the status keeps its parts; :attr:`status` words them when asked
        if self._fault:
            self._state, self._reason = 'frozen', (_FAULT, self._fault)
            changed = self._record(measured, adapt=False)
        elif not excited:
            self._state, self._reason = 'frozen', (_EXCITATION, mon.ms_target)
            changed = self._record(measured, adapt=False)
        else:
            self._state, self._reason = 'adapting', ''
            changed = self._record(measured, adapt=True)
        # the coefficients change only where _record says so (False: unchanged; a
        # method that does not say is checked every step)
        if changed is not False and not math.isfinite(float(np.add.reduce(self._adapted()))):
            self._fall_back('non-finite coefficients')

    def _fall_back(self, reason, fir_cmd=None):
        if self._fallback:
            return fir_cmd
        self._fallback = reason
        self.status = Status('fallback', f'designed FIR in use: {reason}')
        return fir_cmd

    # ----------------------------------------------------------------- subclass hooks
    def _command(self, target):            # pragma: no cover - abstract
        raise NotImplementedError

    def _record(self, measured, adapt):    # pragma: no cover - abstract
        """Take the measurement; adapt if ``adapt``; return False if no coefficient changed."""
        raise NotImplementedError

    def coefficients(self):                # pragma: no cover - abstract
        """Return the current coefficients of the method."""
        raise NotImplementedError

    def _adapted(self):
        """Return the adapted coefficients as they are (no copy; checked finite each step).

        A sum is non-finite exactly when one of them is (or when they overflow it, which
        is a fault too), so the check costs one reduction and no copy.
        """
        return self.coefficients()


def _clip_step(new, old, lower, upper, max_step):
    """Limit ``new`` to ``old +- max_step`` and to ``[lower, upper]`` (arrays, in place).

    A NaN stays NaN (as with ``np.clip``).  A few coefficients (ats, amb) are clipped in
    Python floats: two ``np.clip`` calls cost more than the whole rest of their step.
    """
    if new.size > 8:
        np.clip(new, old - max_step, old + max_step, out=new)
        np.clip(new, lower, upper, out=new)
        return new
    steps = np.broadcast_to(max_step, new.shape).tolist()
    new[:] = _clip_list(new.tolist(), old.tolist(), lower.tolist(), upper.tolist(), steps)
    return new


def _clip_list(new, old, lower, upper, steps):
    """:func:`_clip_step` on Python lists (a new list): the short vectors' arithmetic."""
    return [min(max(min(max(v, o - m), o + m), lo), hi) for v, o, m, lo, hi
            in zip(new, old, steps, lower, upper, strict=True)]


class _Clip:
    """:func:`_clip_step` of a long vector in place with preallocated buffers.

    ``np.clip`` is ``minimum(maximum(x, lo), hi)``, NaN kept: the same four ufuncs here,
    without the temporaries and the dispatch of ``np.clip`` (a few microseconds a step).
    """

    def __init__(self, lower, upper, max_step):
        self.lower, self.upper, self.max_step = lower, upper, float(max_step)
        self.lo = np.empty(lower.shape)
        self.hi = np.empty(lower.shape)
        self._abs = np.empty(lower.shape)
        # room: a lower bound of min_i min(x_i - lower_i, upper_i - x_i) of the current x;
        # a step that moves no coefficient by more than max_step uses up at most ``slack``
        # of it (max_step plus far more than its rounding)
        scale = float(max(np.max(np.abs(lower)), np.max(np.abs(upper)), self.max_step))
        self._margin = 1e-9 * scale
        self.slack = self.max_step * (1.0 + 1e-6) + self._margin
        self.room = 0.0

    def add(self, x, dx):
        """``x <- clip(x + dx)`` in place (:func:`_clip_step` of ``x + dx`` around ``x``).

        When no |dx_i| exceeds max_step and x is farther than that from its bounds, both
        clips are no-ops, exactly (rounding is monotonic: fl(x + dx) lies between
        fl(x - max_step) and fl(x + max_step)), and are skipped: three array calls
        instead of seven.
        """
        move = float(np.maximum.reduce(np.abs(dx, out=self._abs)))
        if move <= self.max_step and self.room > self.slack:     # NaN: the full path
            np.add(x, dx, out=x)
            self.room -= self.slack
            return x
        self.bounds(x)
        self.apply(np.add(x, dx, out=x))
        np.subtract(x, self.lower, out=self._abs)
        below = float(np.minimum.reduce(self._abs))
        np.subtract(self.upper, x, out=self._abs)
        room = min(below, float(np.minimum.reduce(self._abs))) - self._margin
        self.room = room if room > 0.0 else 0.0        # NaN: 0, the full path next time
        return x

    def bounds(self, old):
        """Note the rate limits around ``old`` (before it is overwritten)."""
        np.subtract(old, self.max_step, out=self.lo)
        np.add(old, self.max_step, out=self.hi)

    def apply(self, new):
        """Clip ``new`` in place to the noted rate limits, then to ``[lower, upper]``."""
        np.maximum(new, self.lo, out=new)
        np.minimum(new, self.hi, out=new)
        np.maximum(new, self.lower, out=new)
        np.minimum(new, self.upper, out=new)
        return new


class _Ring:
    """Doubled ring buffer: ``view()`` is the newest-first history of length n."""

    def __init__(self, n):
        self.n = int(n)
        self.buf = np.zeros(2 * self.n)
        self.p = 0

    def push(self, value):
        p = self.p - 1
        if p < 0:
            p = self.n - 1
        self.p = p
        self.buf[p] = value
        self.buf[p + self.n] = value

    def view(self):
        return self.buf[self.p:self.p + self.n]


def split_fir(design: Design, plant, fs_hz=None):
    """Split a designed FIR ``G = A*/B+* . H`` into ``(h, prefilter_num, prefilter_den)``.

    ``taps = A* * h`` (polynomial product), so h is the exact quotient ``taps / A*``.
    """
    _, a_star, _, _ = plant_polynomials(plant, fs_hz or design.fs_hz)
    h, rem = signal.deconvolve(design.taps, a_star)
    if np.max(np.abs(rem)) > 1e-9 * np.max(np.abs(design.taps)):
        raise ValueError('the design is not an FIR compensator A*/B+* . H of this plant '
                         '(its taps are not a multiple of A*); design it with rths design '
                         '--scheme ls|wls|mm on the same plant')
    return np.asarray(h, float), np.asarray(a_star, float), np.asarray(design.denominator, float)


class RlsFir(AdaptiveMethod):
    """FIR compensator whose taps h are estimated by RLS with forgetting (see module doc).

    The covariance is forgotten only along the current regressor (directional forgetting,
    Kulhavy 1987; Bittanti, Bolzern & Campi 1990): a band-limited target excites a few
    directions of the n-tap regression, and uniform exponential forgetting would blow up
    the covariance in all the others (wind-up).  Prior: h0 (the designed taps) with the
    covariance ``prior / (n ms_w) I`` set at the first adapting step, ms_w the running mean
    square of the regressor (so ``phi' P phi`` is about ``prior``; the equation error
    counts 1).  Bounds: each tap stays within ``bound`` x max|h0|
    of its designed value and moves at most ``rate`` x max|h0| per second; the covariance
    trace never exceeds ``trace_factor`` times its initial value.

    Long filters (n > ``n_full``): the n x n covariance would cost O(n^2) per step, so
    the same RLS adapts instead a correction ``C`` of ``n_correction`` taps that multiplies
    the designed H: ``H = H0 (1 + C)``, C started at 0 (its regressor is the measured
    history through H0; each c_i within +-``correction_bound``, moving at most ``rate``
    per second).  A plant change ``T -> T (1 + delta)`` asks ``C = 1/(1 + delta) - 1``,
    smooth over the band: a short FIR spans it (a gain change is c_0 alone).  The cost per
    step is O(n + n_correction^2).
    """

    name = 'rls_fir'

    def __init__(self, design, plant, guards=None, forgetting=0.995, prior=1.0, bound=0.5,
                 rate=2.0, trace_factor=10.0, lowpass_hz=30.0, n_full=32, n_correction=16,
                 correction_bound=2.0):
        super().__init__(design, guards)
        if not 0.9 < forgetting < 1.0:
            raise ValueError(f'rls_fir forgetting factor {forgetting} must lie in (0.9, 1)')
        if int(n_correction) < 1:
            raise ValueError(f'rls_fir n_correction {n_correction} must be >= 1 (taps of the '
                             'correction of a long filter)')
        h0, pre_b, pre_a = split_fir(design, plant, self.fs_hz)
        self.h0 = h0
        self.h = h0.copy()
        n = h0.size
        self.correction = n > int(n_full)
        m = int(n_correction) if self.correction else n
        self.n_adapt = m            # adapted coefficients
        self.lam = float(forgetting)
        if self.correction:
            self.c = np.zeros(m)
            self.lower = np.full(m, -correction_bound)
            self.upper = np.full(m, correction_bound)
            self.max_step = rate * self.dt
            self._s = _Ring(m)      # target history through H0 (the command's correction)
            self._r = _Ring(m)      # regressor history through H0 (the regression's)
        else:
            scale = float(np.max(np.abs(h0)))
            self.lower = h0 - bound * scale
            self.upper = h0 + bound * scale
            self.max_step = rate * scale * self.dt
        self.prior = float(prior)
        self.trace_factor = float(trace_factor)
        self.P = None               # set at the first adapting step (scale of the regressor)
        self.trace_max = np.inf
        self._pre_target = CausalFilter(pre_b, pre_a)
        self._pre_measured = CausalFilter(pre_b, pre_a)
        # the regression runs on low-passed command and regressor (u_f = H w_f still holds):
        # A* amplifies the sensor noise above the band by orders of magnitude
        bl, al = signal.butter(4, lowpass_hz, fs=self.fs_hz)
        self._lp = MultiChannelFilter(bl, al, n_channels=2)      # [w, u]
        self._v = _Ring(n)          # prefiltered target history (the command's regressor)
        self._w = _Ring(n)          # low-passed prefiltered measured history (the regression's)
        self._u_prev = 0.0
        self._ms_w = 0.0
        self._pair = np.zeros(2)
        # the RLS step's buffers (no array allocated per step)
        self._pphi = np.empty(m)
        self._tmp = np.empty(m)
        self._outer = np.empty((m, m))
        self._clip = _Clip(self.lower, self.upper, self.max_step) if m > 8 else None

    def _command(self, target):
        self._v.push(self._pre_target.step(target))
        if self.correction:
            s = float(self.h0 @ self._v.view())
            self._s.push(s)
            u = s + float(self.c @ self._s.view())
        else:
            u = float(self.h @ self._v.view())
        self._u_prev = u
        return u

    def _record(self, measured, adapt):
        pair = self._pair
        pair[0] = self._pre_measured.step(measured)
        pair[1] = self._u_prev
        w_f, u_f = self._lp.step(pair).tolist()
        self._w.push(w_f)
        if self.correction:
            known = float(self.h0 @ self._w.view())
            self._r.push(known)
            phi, theta = self._r.view(), self.c
            u_f -= known
            self._ms_w += self._monitor.alpha * (known * known - self._ms_w)
        else:
            phi, theta = self._w.view(), self.h
            self._ms_w += self._monitor.alpha * (w_f * w_f - self._ms_w)
        if adapt:
            return self._rls(phi, theta, u_f)
        return False

    def _rls(self, phi, theta, u_f):
        """One RLS step of ``u_f = theta . phi``, theta bounded, in place; False: none.

        In place with preallocated buffers: the same products and sums as
        ``P @ phi``, ``theta + pphi * g``, ``np.clip`` and ``P -= np.outer(pphi, pphi * c)``.
        """
        if self.P is None:
            size = phi.size * self._ms_w
            if not size > 0.0:
                return False
            self.P = np.eye(phi.size) * (self.prior / size)
            self.trace_max = self.trace_factor * np.trace(self.P)
            self._diagonal = np.diagonal(self.P)    # a view: P is updated in place
        P = self.P
        pphi = np.matmul(P, phi, out=self._pphi)
        r = float(phi @ pphi)
        if not r > 0.0:
            return False
        err = u_f - theta @ phi
        tmp = np.multiply(pphi, err / (1.0 + r), out=self._tmp)
        clip = self._clip
        if clip is None:
            theta[:] = _clip_step(theta + tmp, theta, self.lower, self.upper, self.max_step)
        else:
            clip.add(theta, tmp)
        # directional forgetting: P <- P - P phi phi' P eps / (lam (1 + r)),
        # eps = lam - (1 - lam) / r  (eps < 0 re-inflates P along phi only)
        eps = self.lam - (1.0 - self.lam) / r
        if eps < 0.0 and np.add.reduce(self._diagonal) > self.trace_max:   # trace(P)
            eps = 0.0
        np.multiply(pphi, eps / (self.lam * (1.0 + r)), out=tmp)
        np.subtract(P, np.multiply.outer(pphi, tmp, out=self._outer), out=P)
        return True

    def _adapted(self):
        return self.c if self.correction else self.h

    def coefficients(self):
        """Return the current taps of H, the adapted part of G.

        A long filter has n + n_correction - 1 of them: ``H0 (1 + C)``.
        """
        if self.correction:
            one_plus_c = self.c.copy()
            one_plus_c[0] += 1.0
            return np.convolve(self.h0, one_plus_c)
        return self.h.copy()


class _Derivatives:
    """Backward-difference derivatives 0..order of a sampled signal (a list of floats)."""

    def __init__(self, order, dt):
        self.order = order
        self.dt = dt
        self.vals = [0.0] * (order + 1)

    def push(self, x):
        """Return ``[x, dx, ..., d^order x]`` of the newest sample ``x`` (a new list)."""
        dt, prev = self.dt, self.vals
        v = [float(x)]
        for i in range(self.order):
            v.append((v[i] - prev[i]) / dt)
        self.vals = v
        return v


def _difference_responses(order, fs_hz, freqs):
    """Frequency responses of the backward-difference derivatives 0..order at ``freqs``."""
    z1 = np.exp(-2j * np.pi * np.asarray(freqs) / fs_hz)
    d = (1.0 - z1) * fs_hz
    return np.array([d ** i for i in range(order + 1)])


def _largest_eigenvalue_sym3(a00, a01, a02, a11, a12, a22):
    """Return the largest eigenvalue of a symmetric 3 x 3 (closed form, Smith 1961).

    Accurate for the largest eigenvalue only (the smallest loses digits when they spread).
    """
    q = (a00 + a11 + a22) / 3.0
    off = a01 * a01 + a02 * a02 + a12 * a12
    p2 = (a00 - q) ** 2 + (a11 - q) ** 2 + (a22 - q) ** 2 + 2.0 * off
    if not p2 > 0.0:
        return q                                  # a multiple of the identity
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22 = (a00 - q) / p, (a11 - q) / p, (a22 - q) / p
    b01, b02, b12 = a01 / p, a02 / p, a12 / p
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02)
               + b02 * (b01 * b12 - b11 * b02))
    return q + 2.0 * p * math.cos(math.acos(min(1.0, max(-1.0, r))) / 3.0)


def solve_spd3(a, b, max_cond=1e12):
    """Solve the symmetric positive definite 3 x 3 system ``a x = b`` in Python floats.

    Returns None when ``a`` is not positive definite or its condition number exceeds
    ``max_cond``.  Cholesky (backward stable); the condition number is the largest
    eigenvalue of ``a`` times that of its inverse (the closed form is accurate for the
    largest eigenvalue, not for the smallest).  A few microseconds where numpy's
    small-matrix calls cost tens: this runs inside a real-time step.
    """
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = a
    if not a00 > 0.0:
        return None
    l00 = math.sqrt(a00)
    l10, l20 = a01 / l00, a02 / l00
    d1 = a11 - l10 * l10
    if not d1 > 0.0:
        return None
    l11 = math.sqrt(d1)
    l21 = (a12 - l20 * l10) / l11
    d2 = a22 - l20 * l20 - l21 * l21
    if not d2 > 0.0:
        return None
    l22 = math.sqrt(d2)
    # inverse of L (lower triangular), then of a: M = inv(L)' inv(L)
    m00, m11, m22 = 1.0 / l00, 1.0 / l11, 1.0 / l22
    m10 = -l10 * m00 * m11
    m21 = -l21 * m11 * m22
    m20 = -(l20 * m00 + l21 * m10) * m22
    i00 = m00 * m00 + m10 * m10 + m20 * m20
    i01 = m10 * m11 + m20 * m21
    i02 = m20 * m22
    i11 = m11 * m11 + m21 * m21
    i12 = m21 * m22
    i22 = m22 * m22
    cond = (_largest_eigenvalue_sym3(a00, a01, a02, a11, a12, a22)
            * _largest_eigenvalue_sym3(i00, i01, i02, i11, i12, i22))
    if not cond <= max_cond:
        return None
    y0 = b[0] / l00
    y1 = (b[1] - l10 * y0) / l11
    y2 = (b[2] - l20 * y0 - l21 * y1) / l22
    x2 = y2 / l22
    x1 = (y1 - l21 * x2) / l11
    x0 = (y0 - l10 * x1 - l20 * x2) / l00
    return x0, x1, x2


class Ats(AdaptiveMethod):
    """Adaptive time-series compensator ``u = a0 x + a1 xd + a2 xdd`` (see module doc).

    Defaults from OpenFresco's ATS set-up (Chae et al. 2013): window 1 s, update every 16th
    step, a0 in [0.5, 2] (OpenFresco: 0.9-1.1; widened for gain drift), a1 in
    [0, 3 tau0], a2 in [0, (3 tau0)^2 / 2], maximum rates [0.2 /s, 5 ms/s, 1e-4 s^2/s],
    the measured displacement and the command low-passed (Butterworth, 20 Hz) before the fit.
    """

    name = 'ats'

    def __init__(self, design, plant, guards=None, window_s=1.0, every=16, band_hz=10.0,
                 rates=(0.2, 0.005, 1e-4), lowpass_hz=20.0):
        super().__init__(design, guards)
        b, a, d, fs = plant_polynomials(plant, self.fs_hz)
        tau = max(0.0, time_delay_ms(np.r_[np.zeros(d), b], a, fs, band_hz) * 1e-3)
        self.a0 = np.array([1.0, tau, 0.5 * tau * tau])
        self.a = self.a0.copy()
        span = 3.0 * max(tau, 1e-3)
        self.lower = np.array([0.5, 0.0, 0.0])
        self.upper = np.array([2.0, span, 0.5 * span * span])
        self.max_step = np.asarray(rates, float) * every * self.dt
        self.every = int(every)
        self.n_window = int(round(window_s * self.fs_hz))
        bl, al = signal.butter(4, lowpass_hz, fs=self.fs_hz)
        self._lp = MultiChannelFilter(bl, al, n_channels=2)      # [measured, command]
        self._dx = _Derivatives(2, self.dt)
        self._dy = _Derivatives(2, self.dt)
        self._rows = np.zeros((2 * self.n_window, 4))              # [y, yd, ydd, u] doubled
        self._p = 0
        self._filled = 0
        self._since = 0
        # the window's normal equations [phi' phi | phi' u] (3 x 4), kept by adding the
        # new row and removing the one it overwrites: a fit costs a 3 x 3 solve, not a pass
        # over the window; summed anew from the window once per window against rounding drift
        self._normal = np.zeros((3, 4))
        self._outer = np.empty((3, 4))
        self._pushed = 0
        self._u_prev = 0.0
        self._pair = np.zeros(2)
        self._a = self.a.tolist()              # self.a in Python floats (the command's)
        self._bounds = (self.lower.tolist(), self.upper.tolist(), self.max_step.tolist())

    def _command(self, target):
        v = self._dx.push(target)
        a = self._a
        u = 0.0                    # a . v summed left to right, as numpy sums 3 terms
        for i in range(3):
            u += a[i] * v[i]
        self._u_prev = u
        return u

    def _record(self, measured, adapt):
        pair = self._pair
        pair[0] = measured
        pair[1] = self._u_prev
        yf, uf = self._lp.step(pair).tolist()
        dy = self._dy.push(yf)
        n = self.n_window
        p = self._p - 1
        if p < 0:
            p = n - 1
        self._p = p
        rows, normal, outer = self._rows, self._normal, self._outer
        row = rows[p]
        # the row leaving the window out (zeros at first), the new one in
        np.subtract(normal, np.multiply.outer(row[:3], row, out=outer), out=normal)
        row[:] = (dy[0], dy[1], dy[2], uf)
        np.add(normal, np.multiply.outer(row[:3], row, out=outer), out=normal)
        rows[p + n] = row
        self._filled = min(self._filled + 1, n)
        self._pushed += 1
        if self._pushed % n == 0:
            w = rows[p:p + n]
            normal[:] = w[:, :3].T @ w
        self._since += 1
        if adapt and self._filled == n and self._since >= self.every:
            self._since = 0
            return self._fit()
        return False

    def _fit(self):
        scale = (1.0, float(self.a0[1] or 1e-3), float(self.a0[2] or 1e-6))
        g = self._normal.tolist()
        gram = [[g[i][j] * scale[i] * scale[j] for j in range(3)] for i in range(3)]
        rhs = [g[i][3] * scale[i] for i in range(3)]
        sol = solve_spd3(gram, rhs, max_cond=1e12)
        if sol is None:
            return False               # window not informative enough: keep the coefficients
        sol = [sol[i] * scale[i] for i in range(3)]
        if all(map(math.isfinite, sol)):
            self._a = _clip_list(sol, self._a, *self._bounds)
            self.a = np.array(self._a)
        return True

    def _adapted(self):
        return self.a

    def coefficients(self):
        """Return the current [a0, a1 (s), a2 (s^2)]."""
        return self.a.copy()


def amb_initial(plant, fs_hz, band_hz=20.0, order=3):
    """Return theta of ``u = sum theta_i D^i x`` (backward differences) inverting the plant.

    Least squares of ``T(f) sum_i theta_i D_i(f) = 1`` on 0 < f <= band_hz, real theta.
    """
    b, a, d, fs = plant_polynomials(plant, fs_hz)
    freqs = np.linspace(band_hz / 200, band_hz, 200)
    _, t = signal.freqz(np.r_[np.zeros(d), b], a, worN=freqs, fs=fs)
    basis = _difference_responses(order, fs, freqs) * t          # (order+1) x nf
    mat = np.vstack([basis.real.T, basis.imag.T])
    rhs = np.r_[np.ones(freqs.size), np.zeros(freqs.size)]
    scale = np.max(np.abs(mat), axis=0)
    theta = np.linalg.lstsq(mat / scale, rhs, rcond=None)[0] / scale
    return theta


class Amb(AdaptiveMethod):
    """Adaptive model-based compensator ``u = theta . [x, xd, xdd, xddd]`` (see module doc).

    Normalised gradient (filtered-x): ``theta_i += mu e psi_i / (eps + n ms_i)`` with psi the
    derivative regressors filtered through the identified plant, e the tracking error, both
    low-passed (Butterworth, ``lowpass_hz``), ms_i the running mean square of psi_i.
    Bounds: theta_0 in [0.5, 2], theta_i in [0, 4 theta_i0]; rate ``rate`` x |theta_i0| per s.
    """

    name = 'amb'

    def __init__(self, design, plant, guards=None, band_hz=20.0, mu=0.01, rate=1.0,
                 lowpass_hz=20.0):
        super().__init__(design, guards)
        b, a, d, fs = plant_polynomials(plant, self.fs_hz)
        self.theta0 = amb_initial(plant, self.fs_hz, band_hz)
        self.theta = self.theta0.copy()
        mag = np.abs(self.theta0)
        self.lower = np.r_[0.5, np.minimum(0.0, 4 * self.theta0[1:])]
        self.upper = np.r_[2.0, np.maximum(4 * self.theta0[1:], 0.0)]
        self.max_step = rate * mag * self.dt
        self.mu = float(mu)
        self._dx = _Derivatives(3, self.dt)
        self._model = MultiChannelFilter(np.r_[np.zeros(d), b], a, n_channels=4)
        bl, al = signal.butter(2, lowpass_hz, fs=self.fs_hz)
        self._lp = MultiChannelFilter(bl, al, n_channels=5)       # [e, psi_0..3]
        self._psi_now = np.zeros(4)
        self._psi_prev = np.zeros(4)
        self._ms = [0.0] * 4
        self._alpha = 1.0 / (self.guards.window_s * self.fs_hz)
        self._buf = np.zeros(5)
        self._v = np.zeros(4)
        self._theta = self.theta.tolist()      # self.theta in Python floats
        self._bounds = (self.lower.tolist(), self.upper.tolist(), self.max_step.tolist())

    def _command(self, target):
        v = self._dx.push(target)
        self._v[:] = v
        self._psi_now = self._model.step(self._v)
        theta = self._theta
        u = 0.0                    # theta . v summed left to right, as numpy sums 4 terms
        for i in range(4):
            u += theta[i] * v[i]
        return u

    def _record(self, measured, adapt):
        buf = self._buf
        buf[0] = self._prev_target - measured
        buf[1:] = self._psi_prev
        f = self._lp.step(buf).tolist()
        e, psi = f[0], f[1:]
        alpha, ms = self._alpha, self._ms
        for i in range(4):
            ms[i] += alpha * (psi[i] * psi[i] - ms[i])
        if not adapt:
            return False
        gain = self.mu * e
        theta = self._theta
        new = [theta[i] + gain * psi[i] / (1e-30 + 4.0 * ms[i]) for i in range(4)]
        self._theta = _clip_list(new, theta, *self._bounds)
        self.theta = np.array(self._theta)
        return True

    def step(self, target, measured_prev=None):
        """As :meth:`AdaptiveMethod.step`; keeps the plant-filtered regressor of step k-1."""
        self._psi_prev[:] = self._psi_now
        return super().step(target, measured_prev)

    def _adapted(self):
        return self.theta

    def coefficients(self):
        """Return the current theta [-, s, s^2, s^3]."""
        return self.theta.copy()


def make_method(name, design: Design, plant=None, guards: Guards = None, **options):
    """Build the method ``name`` (:data:`.methods.METHODS`) from a designed FIR and its plant."""
    entry = METHODS.entry(name)
    return entry.method_class().from_design(design, plant, guards, **options)


#: Severity order of the states when several channels report (the worst is shown).
_SEVERITY = {'fixed': 0, 'adapting': 1, 'frozen': 2, 'fallback': 3}


class ChannelMethods:
    """One method per interface channel: what the compensator node and the offline loop run.

    ``step(x, measured_prev)`` takes one target per channel and the measured displacements
    of the previous step (or None); ``applied_prev`` (the commands the bridge actually
    wrote, if known) freezes adaptation while the bridge changes the commands (a hold, a
    ramp or a limit: the measurement then does not answer the compensator's command).
    """

    def __init__(self, name, design: Design, plant=None, n_channels=1, **options):
        self.name = name
        self.methods = [make_method(name, design, plant, **options)
                        for _ in range(int(n_channels))]
        self._last = [0.0] * int(n_channels)

    def step(self, x, measured_prev=None, applied_prev=None):
        """Return the commands (array) for the targets ``x`` of this step."""
        # Python floats throughout (one tolist per input): a real-time step
        x = x.tolist() if isinstance(x, np.ndarray) else [float(v) for v in x]
        applied = None if applied_prev is None else np.asarray(applied_prev, float).tolist()
        measured = None if measured_prev is None else np.asarray(measured_prev, float).tolist()
        last = self._last
        out = []
        for i, method in enumerate(self.methods):
            if applied is not None and i < len(applied):
                if abs(applied[i] - last[i]) > 1e-12:
                    method.flag_fault('the bridge changed the command (hold, ramp or limit)')
                else:
                    method.clear_fault()
            prev = None if measured is None or i >= len(measured) else measured[i]
            out.append(float(method.step(x[i], prev)))
        self._last = out
        return np.array(out)

    def coefficients(self):
        """Coefficients of every channel, concatenated (channel 0 first)."""
        return np.concatenate([m.coefficients() for m in self.methods])

    @property
    def status(self) -> Status:
        """Return the worst channel's status: fallback > frozen > adapting > fixed."""
        worst = max(self.methods, key=lambda m: _SEVERITY.get(m.status.state, 0))
        return worst.status

    @property
    def fallback(self) -> str:
        """Return '' or the first fallen-back channel's status reason (cheap: every step).

        The :attr:`status` reason when its state is ``fallback``.
        """
        for method in self.methods:
            if getattr(method, '_fallback', ''):
                return method.status.reason
        return ''


def methods_from_params(params: dict, n_channels: int) -> ChannelMethods:
    """Build the compensator parameters' ``method`` (default fir) for ``n_channels`` channels.

    ``taps``/``denominator``/``fs_hz``/``scheme`` are the designed filter; an adaptive
    method also needs the plant.yaml the FIR was designed on: ``plant``, or the provenance's
    (``provenance: {plant: ...}`` in a file, ``provenance.plant`` in a node).
    """
    entry = method_of(params, 'parameter method')
    name = str(params.get('method') or DEFAULT)
    design = Design(str(params.get('scheme', '')), np.asarray(params['taps'], float),
                    np.asarray(params.get('denominator', [1.0]), float),
                    float(params.get('fs_hz', 1024.0)))
    plant = None
    if entry.adaptive:
        provenance = params.get('provenance') or {}
        path = str(params.get('plant') or provenance.get('plant')
                   or params.get('provenance.plant') or '')
        if not path:
            raise ValueError(f'parameter method = {name}: parameter provenance.plant (the '
                             'plant.yaml the FIR was designed on) is missing')
        plant = load_plant(path)
    options = entry.method_class().options_from_params(params)
    return ChannelMethods(name, design, plant, n_channels, **options)
