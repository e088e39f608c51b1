"""The receiver's AC coupling: a first-order high-pass between the detector and the threshold, applied to the
atmosphere's volume return.

A front end coupled through a capacitor answers a signal x(r) (range units, m; time t = 2 r / c) with::

    y(r) = x(r) - (1/tau) * integral_{-inf}^{r} x(r') exp(-(r - r') / tau) dr'

``tau`` the coupling's time constant in range units (m). A short pulse passes as a positive lobe followed by an
undershoot of the same area spread over ~tau behind it; a signal slow against tau is answered only where it
changes (y ~ tau dx/dr). The simulator's pulse (``pulse.fwhm_m``) is fitted to measured hard-target EPWs, so it
already is the filtered pulse's lobe; its undershoot stays below the threshold and is left out. What the fitted
pulse cannot hold is the filter's answer to a return metres long: fog's volume, which a DC-coupled model turns
into one echo 3-12 m wide in every beam (``git show f643197:benchmarks/receiver_highpass.py``). So the filter is
applied to the volume's density before it meets the pulse: the volume return becomes the pulse convolved with the
filtered density, ``HP(V) * p`` (= ``HP(V * p)``, the fitted pulse standing in for the unfiltered one).

The density arrives as slabs (:class:`lidar_weather_sim.regions.volume_return.VolumeReturn`): slab k, of
amount A_k spread evenly over [a_k, b_k], loses to the filter the share of the tails of itself and of the
slabs before it that falls inside [a_k, b_k] (exact for piecewise-uniform densities)::

    E_k = exp(-h_k / tau),  f_k = (tau / h_k) (1 - E_k),  h_k = b_k - a_k
    lost_k = T (1 - E_k) + A_k (1 - f_k),    T <- T E_k + A_k f_k    (T: tail mass at b_{k-1}, decayed to a_k)

What is left, ``A_k - lost_k``, is negative after the volume's rise; the echo stage takes no negative pulses,
so it is clipped at 0 there: the undershoot would lower whatever follows by ~tau |dV/dr|.
"""

from __future__ import annotations

import numba
import numpy as np


def highpass_slabs(amount: np.ndarray, lower_m: np.ndarray, upper_m: np.ndarray, row: np.ndarray,
                   tau_m: float) -> np.ndarray:  # fmt: skip
    """The slabs' ``amount`` (any linear unit) after the high-pass of time constant ``tau_m`` (m; 0: unchanged),
    clipped at 0. Slab i spans [lower_m[i], upper_m[i]] (m) of beam ``row[i]``; the slabs of a beam are
    consecutive and in range order (gaps between them allowed)."""
    amount = np.asarray(amount, dtype=np.float64)
    if tau_m <= 0 or not len(amount):
        return amount
    return _highpass(amount, np.asarray(lower_m, np.float64), np.asarray(upper_m, np.float64),
                     np.asarray(row, np.int64), float(tau_m), np.empty(len(amount)))  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _highpass(a, lo, hi, row, tau, out):
    tail = 0.0
    end = 0.0
    for i in range(len(a)):
        if i == 0 or row[i] != row[i - 1]:
            tail = 0.0
        else:
            tail *= np.exp(-(lo[i] - end) / tau)
        h = hi[i] - lo[i]
        e = np.exp(-h / tau)
        f = tau / h * (1.0 - e) if h > 0 else 1.0
        out[i] = max(a[i] - tail * (1.0 - e) - a[i] * (1.0 - f), 0.0)
        tail = tail * e + a[i] * f
        end = hi[i]
    return out
