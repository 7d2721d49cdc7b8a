"""The review's plots: the building's response, the actuator's tracking and FRF, hysteresis loops.

Each writes one PNG into the review's directory; :mod:`rths_review.report_html` embeds them
(``PLOTS`` there names them in page order).
"""

import numpy as np
from scipy import signal
from scipy.signal import coherence

from rths_common.rig import DOF_UNITS, DOFS
from rths_compensator.indicators import frf_h1

#: Length [s] of the tracking plot's window around the peak.
ZOOM_S = 3.0
#: The plot of a hysteretic specimen's measured force against its stroke (report_html.PLOTS).
HYSTERESIS_PNG = 'specimen_hysteresis.png'


def _pyplot():
    """Return matplotlib.pyplot on the file-only Agg backend."""
    # lazy: start-up cost: matplotlib (~0.5 s), which only the plots need
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def hysteresis_plot(path, stroke, force, fs, title, labels=('stroke [mm]', 'force [N]'),
                    velocity=True):
    """Force against stroke (and against velocity, by finite differences) of a specimen."""
    plt = _pyplot()
    fig, ax = plt.subplots(1, 2 if velocity else 1, figsize=(10 if velocity else 6, 4),
                           squeeze=False)
    ax = ax[0]
    ax[0].plot(stroke * 1e3, force, lw=0.5)
    ax[0].set_xlabel(labels[0])
    ax[0].set_ylabel(labels[1])
    if velocity:
        ax[1].plot(np.gradient(stroke) * fs * 1e3, force, lw=0.5)
        ax[1].set_xlabel('velocity [mm/s]')
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def review_plots(out_dir, fs, desired, applied, measured, floor2, ref_disp, unc_disp):
    """Plot the 2nd floor (RTHS, reference, uncontrolled building), then the tracking."""
    plt = _pyplot()
    t = np.arange(desired.size) / fs
    fig, ax = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True)
    ax[0].plot(t, unc_disp * 1e3, color='0.6', lw=0.8, label='uncontrolled (numerical)')
    if ref_disp is not None:
        ax[0].plot(t, ref_disp * 1e3, lw=1.0,
                   label='reference: building + specimens (numerical)')
    ax[0].plot(t, floor2 * 1e3, '--', lw=1.0, label='RTHS')
    ax[0].set_ylabel('2nd-floor displacement [mm]')
    ax[0].legend(loc='upper right', fontsize=8)
    if ref_disp is None:   # an external controller's specimen: no model, no reference
        ax[1].plot(t, (floor2 - unc_disp) * 1e3, lw=0.8)
        ax[1].set_ylabel('RTHS - uncontrolled [mm]')
    else:
        ax[1].plot(t, (floor2 - ref_disp) * 1e3, lw=0.8)
        ax[1].set_ylabel('RTHS - reference [mm]')
    ax[1].set_xlabel('time [s]')
    fig.tight_layout()
    fig.savefig(out_dir / 'time_history.png', dpi=110)
    plt.close(fig)
    tracking_plots(out_dir, fs, desired, applied, measured)


def tracking_plots(out_dir, fs, desired, applied, measured, suffix: str = '', title: str = ''):
    """Tracking around the peak and the measured FRF of the actuator (table 5's plots).

    ``suffix`` goes before ``.png`` of both files and ``title`` above both plots (one
    actuator of several: ``_1``, ``actuator 1 (lower)``).
    """
    plt = _pyplot()
    t = np.arange(desired.size) / fs
    k = int(np.argmax(np.abs(desired)))
    lo, hi = max(0, k - int(ZOOM_S * fs / 2)), min(desired.size, k + int(ZOOM_S * fs / 2))
    fig, ax = plt.subplots(figsize=(10, 4))
    ax.plot(t[lo:hi], desired[lo:hi] * 1e3, label='interface displacement (desired)')
    ax.plot(t[lo:hi], applied[lo:hi] * 1e3, lw=0.8, label='command (compensated)')
    ax.plot(t[lo:hi], measured[lo:hi] * 1e3, '--', label='measured')
    ax.set_xlabel('time [s]')
    ax.set_ylabel('actuator displacement [mm]')
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(out_dir / f'tracking_zoom{suffix}.png', dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    nperseg = int(min(desired.size, 4 * round(fs)))
    for x, label in ((applied, 'plant: command -> measured'),
                     (desired, 'compensated: desired -> measured')):
        f, h = frf_h1(x, measured, fs, nperseg)
        _, coh = coherence(x, measured, fs=fs, nperseg=nperseg)
        _, pxx = signal.welch(x, fs=fs, nperseg=nperseg)
        # An earthquake response has little energy above ~10 Hz; there the estimate is window
        # leakage of the low-frequency content (coherent, but meaningless).  Show only bins the
        # data determine: coherence > 0.9 and power within 60 dB of the peak.
        h = np.where((coh > 0.9) & (pxx > 1e-6 * pxx.max()), h, np.nan)
        sel = (f > 0) & (f <= 30)
        ax[0].plot(f[sel], 20 * np.log10(np.abs(h[sel])), '.-', ms=3, label=label)
        ax[1].plot(f[sel], np.degrees(np.angle(h[sel])), '.-', ms=3, label=label)
    ax[0].set_ylabel('magnitude [dB]')
    ax[1].set_ylabel('phase [deg]')
    ax[1].set_xlabel('frequency [Hz]')
    ax[0].legend(fontsize=8)
    ax[0].set_title(f'Measured FRF of {title or "the actuator"} (H1) during the RTHS\n'
                    '(bins with coherence > 0.9 and power within 60 dB of the peak)', fontsize=10)
    fig.tight_layout()
    fig.savefig(out_dir / f'bode_actuator{suffix}.png', dpi=110)
    plt.close(fig)


def interface_plot(path, fs, desired, measured, forces=None, title=''):
    """Plot the interface DOFs x [mm] and theta [mrad]: desired, measured and their error.

    ``forces`` (F [N], M [N m] at the node) go below when given (a rig of several actuators).
    """
    plt = _pyplot()
    t = np.arange(desired.shape[0]) / fs
    rows = 3 if forces is None else 4
    fig, ax = plt.subplots(rows, 1, figsize=(10, 2.4 * rows), sharex=True)
    for i, name in enumerate(DOFS):
        _, unit, scale = DOF_UNITS[name]
        ax[i].plot(t, desired[:, i] * scale, lw=0.9, label=f'{name} desired')
        ax[i].plot(t, measured[:, i] * scale, '--', lw=0.9, label=f'{name} measured')
        ax[i].set_ylabel(f'{name} [{unit}]')
        ax[i].legend(loc='upper right', fontsize=8)
        ax[2].plot(t, (measured[:, i] - desired[:, i]) * scale, lw=0.7,
                   label=f'{name} [{unit}]')
    ax[2].set_ylabel('measured - desired')
    ax[2].legend(loc='upper right', fontsize=8)
    if forces is not None:
        ax[3].plot(t, forces[:, 0] * 1e-3, lw=0.8, label='F [kN]')
        ax[3].plot(t, forces[:, 1] * 1e-3, lw=0.8, label='M [kN m]')
        ax[3].set_ylabel('at the node')
        ax[3].legend(loc='upper right', fontsize=8)
    ax[-1].set_xlabel('time [s]')
    if title:
        ax[0].set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
