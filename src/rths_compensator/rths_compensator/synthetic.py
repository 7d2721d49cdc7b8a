"""Synthetic lab actuators: known plants for testing identification and design end to end.

A :class:`SyntheticActuator` is a continuous-time servo-hydraulic actuator model
``T(s) = e^{-s tau} K / prod(s - p_i)`` (unit DC gain, as eq. 3) sampled with a zero-order
hold at ``fs_hz``.  The transport delay ``tau`` need not be a whole number of samples: the
exact ZOH equivalent of a fractional delay (the modified z-transform) is one rational
transfer function ``z^-m (c0 + c1 z^-1 + ... ) / A(z^-1)`` with one more numerator
coefficient than the delay-free plant, so the TRUE discrete plant is known exactly
(:meth:`SyntheticActuator.model`).  That is what the "floor" of the identification
benchmark designs on.

Timing convention of the project (rths_compensator.plants): the command u_k is held for
one sample and the measurement labelled k is read at the end of it, so the one-sample ZOH
delay is not counted: a delay-free plant has d = 0.

:func:`identification_record` drives an actuator with band-limited white noise and adds
white measurement noise given as a percentage of the output RMS, as a DAQ would record it.
"""

import dataclasses

import numpy as np
from scipy import linalg, signal

from rths_numerical.signals import blwn

from .identification import ArxModel


def _zoh_blocks(a_c, b_c, dt, frac):
    """``(phi, gamma_late, gamma_early)`` of the ZOH of ``x' = A x + B u(t - frac dt)``.

    Over one sample ``[k dt, (k + 1) dt)`` the delayed input is ``u_{k-1}`` for the first
    ``frac dt`` and ``u_k`` after it: ``x_{k+1} = phi x_k + gamma_late u_k + gamma_early
    u_{k-1}`` (Franklin, Powell & Workman, Digital Control, section 4.3.4).
    """
    n = a_c.shape[0]

    def integral(tau):
        big = np.zeros((n + 1, n + 1))
        big[:n, :n] = a_c * tau
        big[:n, n:] = b_c * tau
        e = linalg.expm(big)
        return e[:n, :n], e[:n, n:]

    phi, _ = integral(dt)
    phi_late, gamma_late = integral(dt * (1.0 - frac))
    _, gamma_frac = integral(dt * frac)
    gamma_early = phi_late @ gamma_frac
    return phi, gamma_late, gamma_early


@dataclasses.dataclass
class SyntheticActuator:
    """Continuous-time actuator: unit-DC-gain poles [rad/s] and a transport delay [s]."""

    poles: np.ndarray
    delay_s: float
    fs_hz: float

    def __post_init__(self):
        self.poles = np.atleast_1d(np.asarray(self.poles, dtype=complex))
        if np.any(self.poles.real >= 0):
            raise ValueError('synthetic actuator poles must lie in the left half-plane')
        if not self.delay_s >= 0:
            raise ValueError(f'delay_s must be >= 0, got {self.delay_s}')

    def continuous(self):
        """``(num, den)`` in s of the delay-free part (unit DC gain)."""
        den = np.real(np.poly(self.poles))
        return np.array([float(np.real(np.prod(-self.poles)))]), den

    def model(self) -> ArxModel:
        """Return the exact discrete plant (ZOH, fractional delay) as an :class:`ArxModel`."""
        dt = 1.0 / self.fs_hz
        num, den = self.continuous()
        ss = signal.tf2ss(num, den)
        a_c, b_c, c_c = ss[0], ss[1], ss[2]
        steps = self.delay_s * self.fs_hz
        m = int(np.floor(steps + 1e-9))
        frac = steps - m
        phi, g_late, g_early = _zoh_blocks(a_c, b_c, dt, frac)
        # y_{k+1} = C x_{k+1}; labelled k in the project's convention (see module docstring)
        a = np.real(np.poly(phi))
        n = a.size - 1
        # numerator of C (zI - phi)^-1 (g_late + g_early z^-1), in z^-1 after the shift
        b_late = _numerator(phi, g_late, c_c, a)
        b_early = _numerator(phi, g_early, c_c, a)
        b = np.zeros(n + 1)
        b[:n] += b_late
        b[1:] += b_early
        b = np.trim_zeros(b, 'b')
        if abs(b[0]) < 1e-14 * np.max(np.abs(b)):
            b, m = b[1:], m + 1
        return ArxModel(a=a, b=b, d=m, fs_hz=self.fs_hz)

    def simulate(self, command, noise_pct: float = 0.0, rng=None) -> np.ndarray:
        """Return the measured displacement for ``command`` (from rest).

        White noise of ``noise_pct`` percent of the noise-free output's RMS is added.
        """
        y = self.model().simulate(command)
        if noise_pct > 0:
            rng = np.random.default_rng(rng)
            y = y + rng.standard_normal(y.size) * (noise_pct / 100.0) * np.sqrt(np.mean(y ** 2))
        return y

    def phase_delay_ms(self, f_hz) -> np.ndarray:
        """Phase delay ``-arg T(f) / (2 pi f)`` [ms] of the continuous plant (with tau)."""
        f = np.atleast_1d(np.asarray(f_hz, dtype=float))
        num, den = self.continuous()
        _, h = signal.freqs(num, den, worN=2 * np.pi * f)
        phase = np.unwrap(np.angle(h))
        return (-phase / (2 * np.pi * f) + self.delay_s) * 1e3


def _numerator(phi, gamma, c_c, a):
    """Numerator coefficients (z^-1, n of them) of ``z^-1 C adj(I - z^-1 phi) gamma / A``."""
    n = phi.shape[0]
    # Markov parameters h_j = C phi^(j) gamma; b = conv(a, h) truncated to n coefficients
    h = np.empty(n)
    v = gamma[:, 0]
    for j in range(n):
        h[j] = float(c_c[0] @ v)
        v = phi @ v
    return np.convolve(a, h)[:n]


def random_actuator(rng, fs_hz: float, delay_s: float, n_poles: int) -> SyntheticActuator:
    """Draw a plausible servo-hydraulic actuator: 2-4 poles, 14-30 Hz, damping 0.3-0.7.

    Two poles: one damped pair; three: the pair and a real pole; four: two pairs (the
    second 1.5-3x faster), as the seed's Table 1 models.
    """
    rng = np.random.default_rng(rng)
    if n_poles not in (2, 3, 4):
        raise ValueError(f'n_poles must be 2, 3 or 4, got {n_poles}')
    wn = 2 * np.pi * rng.uniform(14.0, 30.0)
    zeta = rng.uniform(0.3, 0.7)
    pair = wn * (-zeta + 1j * np.sqrt(1 - zeta ** 2))
    poles = [pair, np.conj(pair)]
    if n_poles == 3:
        poles.append(-wn * rng.uniform(0.8, 2.0))
    elif n_poles == 4:
        w2, z2 = wn * rng.uniform(1.5, 3.0), rng.uniform(0.4, 0.8)
        p2 = w2 * (-z2 + 1j * np.sqrt(1 - z2 ** 2))
        poles += [p2, np.conj(p2)]
    return SyntheticActuator(np.array(poles), delay_s, fs_hz)


def identification_record(actuator: SyntheticActuator, duration_s: float = 60.0,
                          band_hz: float = 40.0, peak: float = 0.005, noise_pct: float = 0.5,
                          rng=None):
    """``(time, command, measured)`` of a BLWN identification test of ``actuator``."""
    rng = np.random.default_rng(rng)
    u = blwn(duration_s, actuator.fs_hz, band_hz, peak, rng, taper_s=0.5)
    y = actuator.simulate(u, noise_pct, rng)
    t = np.arange(u.size) / actuator.fs_hz
    return t, u, y


def tracking_signals(fs_hz: float, duration_s: float = 20.0, peak: float = 0.005,
                     seed: int = 5) -> dict:
    """Return the two desired displacements of the tracking checks, ``name -> array``.

    ``sine``: 1 Hz + 5 Hz, equal amplitudes, faded in over 1 s (a causal compensator cannot
    follow a sine that starts with a jump in velocity); ``noise``: band-limited white noise
    0-10 Hz (:func:`rths_numerical.signals.blwn`, 0.5 s tapers).  Both peak at ``peak``.
    """
    t = np.arange(int(round(duration_s * fs_hz))) / fs_hz
    fade = 0.5 * (1 - np.cos(np.pi * np.minimum(1.0, t)))
    sine = (np.sin(2 * np.pi * t) + np.sin(2 * np.pi * 5 * t)) * fade
    return {'sine': sine * (peak / np.max(np.abs(sine))),
            'noise': blwn(duration_s, fs_hz, 10.0, peak, seed, 0.5)}


def tracking(actuator: SyntheticActuator, taps, denominator, desired) -> dict:
    """Track ``desired`` through the TRUE actuator with the compensator ``taps/denominator``.

    Returns ``tracking_pct`` (eq. 43, noise-free response) and ``command_ratio`` (command
    peak over desired peak), and the command's peak velocity and acceleration.
    """
    command = signal.lfilter(taps, denominator, desired)
    y = actuator.model().simulate(command)
    fs = actuator.fs_hz
    return {'tracking_pct': float(100 * np.linalg.norm(y - desired) / np.linalg.norm(desired)),
            'command_ratio': float(np.max(np.abs(command)) / np.max(np.abs(desired))),
            'command_peak_m': float(np.max(np.abs(command))),
            'command_velocity_m_s': float(np.max(np.abs(np.diff(command))) * fs),
            'command_acceleration_m_s2': float(np.max(np.abs(np.diff(command, 2))) * fs ** 2)}
