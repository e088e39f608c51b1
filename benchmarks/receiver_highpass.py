"""What an AC-coupled receiver, or the aperture's defocus, makes of fog's volume return (a receiver
model; the simulator's is :mod:`lidar_weather_sim.sensor.ac_coupling`, applied to the volume only).

The physical atmosphere (``regions/physical_air.py``) and the reference both give, in fog, one echo per
beam 12-16 m wide, where the thesis measured a 0.94 m EPW in 0-5 m (Table 3). A receiver front end that is
AC-coupled (a first-order high-pass of time constant tau, here in range units: m) passes a short pulse
almost unchanged but answers a slowly varying signal only where it changes. This script takes the fog's
volume density of a profile (:class:`lidar_weather_sim.regions.volume_return.VolumeReturn`, no hard target:
``C pi beta O(r) exp(-2 alpha r) / r^2``), filters it with the high-pass, convolves it with the profile's
pulse and thresholds it at the dark threshold, as the echo stage does; and it reports the first echo's
start, peak and EPW per visual range and tau, with the EPW a hard target's lone pulse at 10x the threshold
then has (with and without the filter) beside it.

``--overlap cone|defocus`` sets the profile's overlap model (default: its own; scala4 ships ``defocus``, the
receiver aperture's blur on its field stop, which the cone model of
:func:`~lidar_weather_sim.physics.overlap.biaxial_overlap` leaves out); the overlap itself is printed first at
a few ranges. Here the high-pass also acts on the lone target's pulse (the simulator's fitted pulse already is
the filtered one).

    python benchmarks/receiver_highpass.py [--profile scala4] [--taus 0,0.25,0.5,1,2,4] [--ranges 30,100,500]
        [--overlap cone|defocus]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
from scipy.signal import lfilter

from lidar_weather_sim.regions.physical_air import PhysicalAir
from lidar_weather_sim.testing.fixtures import receiver_variant

DR = 0.005  # grid step (m)
OVERLAP_RANGES_M = (0.5, 0.7, 1.0, 1.4, 1.8, 2.5, 3.5, 5.0, 7.0, 10.0, 20.0)


def highpass(x: np.ndarray, tau_m: float) -> np.ndarray:
    """First-order high-pass y = x - (1/tau) integral x(r') exp(-(r - r') / tau) dr' on the grid (tau 0: x)."""
    if tau_m <= 0:
        return x
    decay = np.exp(-DR / tau_m)
    return x - lfilter([DR / tau_m], [1.0, -decay], x)


def first_echo(r: np.ndarray, w: np.ndarray, thr: float) -> tuple[float, float, float] | None:
    """(start, peak, EPW) in m of the first interval where ``w`` > ``thr``, or None."""
    above = np.flatnonzero(w > thr)
    if not len(above):
        return None
    breaks = np.flatnonzero(np.diff(above) > 1)
    run = above[: breaks[0] + 1] if len(breaks) else above
    return r[run[0]], r[run[np.argmax(w[run])]], r[run[-1]] - r[run[0]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", default="scala4")
    parser.add_argument("--taus", default="0,0.25,0.5,1,2,4", help="high-pass time constants, m of range (0: none)")
    parser.add_argument("--ranges", default="30,100,500", help="fog visual ranges (m)")
    parser.add_argument("--overlap", choices=("cone", "defocus"),
                        help="the profile's optics with this overlap model (default: the profile's own)")
    args = parser.parse_args()
    profile = receiver_variant(args.profile, args.overlap, 0.0)  # the volume before any receiver filter
    r = np.arange(0.0, 60.0, DR)
    volume = PhysicalAir(profile, 500.0, None).volume
    print(f"{args.profile} overlap ({profile.optics.overlap_model}): " + ", ".join(
        f"{x:g} m {o:.3f}" for x, o in zip(OVERLAP_RANGES_M, volume.overlap(np.array(OVERLAP_RANGES_M)))))
    print(f"{args.profile}: pulse FWHM {profile.pulse.fwhm_m} m; first echo of the fog's volume return "
          "(start / peak / EPW, m; peak over threshold) and a lone hard-target pulse at 10x threshold (EPW, m)")
    print("| tau m | " + " | ".join(f"fog {v} m" for v in args.ranges.split(",")) + " | target EPW |")
    print("|---:|" + "---|" * (len(args.ranges.split(",")) + 1))
    for tau in (float(t) for t in args.taus.split(",")):
        cells = []
        for visual_range in (float(v) for v in args.ranges.split(",")):
            air = PhysicalAir(profile, visual_range, None)
            s, thr = air.volume.sigma_m, air.threshold
            pulse = np.exp(-0.5 * (np.arange(-6 * s, 6 * s + DR, DR) / s) ** 2)
            density = replace(volume, alpha=air.volume.alpha).density(r) * air.fog.beta * (r >= volume.overlap_start_m)
            w = np.convolve(highpass(density, tau), pulse, mode="same") * DR
            echo = first_echo(r, w, thr)
            shape = None if echo is None else " / ".join(f"{x:.2f}" for x in echo)
            cells.append("none" if echo is None else f"{shape} ({w.max() / thr:.0f}x)")
        target = np.zeros_like(r)
        target[int(round(20.0 / DR))] = 10.0 * thr / DR / (s * np.sqrt(2.0 * np.pi))  # a pulse of peak 10 T at 20 m
        echo = first_echo(r, np.convolve(highpass(target, tau), pulse, mode="same") * DR, thr)
        target_epw = "none" if echo is None else f"{echo[2]:.2f}"
        print(f"| {tau:g} | " + " | ".join(cells) + f" | {target_epw} |")


if __name__ == "__main__":
    main()
