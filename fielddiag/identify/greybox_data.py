"""Data of the grey-box fit: the wheel motion that drives the model and the body
acceleration it is compared with, per session; reading them from sessions and drives."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fielddiag.drive import accel_unit_factor
from fielddiag.errors import FieldDiagError, InsufficientDataError
from fielddiag.units import ACCEL_UNITS, GRAVITY_MPS2

__all__ = ["ACCEL_UNITS", "GRAVITY_MPS2", "GreyBoxData", "accel_unit_factor", "default_band_hz"]



@dataclass
class GreyBoxData:
    """One stretch of recording ready for the fit.

    Attributes
    ----------
    sample_rate_hz : float
        Uniform sample rate [Hz].
    wheel_disp_m, wheel_vel_mps : ndarray
        Wheel motion (input of the body model), valid in ``band_hz``.
    body_accel_mps2 : ndarray
        Measured body acceleration without g, limited to the same band as the wheel motion.
    added_mass_kg : float
        Mass added on the body during this recording.
    name : str
        Label for reports (file name, segment).
    body_disp_m, body_vel_mps : ndarray or None
        Integrated body motion (for equation-error start values), if available.
    band_hz : (float, float) or None
        Band in which the signals are valid and the residual is compared; None for
        full-band data (simulator truth).
    start_s : float
        Time of the first sample in the recording.
    ride_height_restored : bool
        The added mass's weight is carried by a levelling system (self-levelling
        suspension, or the ride height re-set by the technician): the drive moves about
        the unloaded static deflection instead of sagging by the added mass's weight.
    disturbance_basis : ndarray or None
        ``(n_samples, p)``: shapes of known form and unknown size in the body acceleration
        that no model parameter explains (what each clipped peak of the wheel reading lost,
        :mod:`fielddiag.diagnose.clipping`). Their sizes are fitted with every model by
        variable projection: the residual and its Jacobian are taken orthogonal to them.
    """

    sample_rate_hz: float
    wheel_disp_m: np.ndarray
    wheel_vel_mps: np.ndarray
    body_accel_mps2: np.ndarray
    added_mass_kg: float = 0.0
    name: str = ""
    body_disp_m: np.ndarray | None = None
    body_vel_mps: np.ndarray | None = None
    band_hz: tuple[float, float] | None = None
    start_s: float = 0.0
    ride_height_restored: bool = False
    disturbance_basis: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = np.asarray(self.body_accel_mps2).size
        for attr in ("wheel_disp_m", "wheel_vel_mps", "body_accel_mps2", "body_disp_m",
                     "body_vel_mps"):
            v = getattr(self, attr)
            if v is None:
                continue
            v = np.ascontiguousarray(v, dtype=float).reshape(-1)
            if v.size != n:
                raise FieldDiagError(f"GreyBoxData: {attr} has {v.size} samples, body "
                                     f"acceleration {n}; give equal-length arrays")
            if not np.all(np.isfinite(v)):
                raise FieldDiagError(f"GreyBoxData {self.name!r}: {attr} holds NaN or inf; "
                                     "cut the segment around gaps or clipped samples")
            setattr(self, attr, v)
        if not (self.sample_rate_hz > 0 and math.isfinite(self.sample_rate_hz)):
            raise FieldDiagError(f"GreyBoxData: sample_rate_hz={self.sample_rate_hz!r} invalid")
        if self.disturbance_basis is not None:
            b = np.asarray(self.disturbance_basis, dtype=float)
            if b.ndim != 2 or b.shape[0] != n or not np.all(np.isfinite(b)):
                raise FieldDiagError(f"GreyBoxData {self.name!r}: disturbance_basis must be "
                                     f"finite, ({n}, p); it is {b.shape}")
            self.disturbance_basis = b

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.body_accel_mps2.size)

    @property
    def duration_s(self) -> float:
        """Duration of the data [s] (``n_samples / sample_rate_hz``)."""
        return self.n_samples / self.sample_rate_hz

    @property
    def travel_per_sample_m(self) -> float:
        """Rms suspension travel per sample interval [m]: the relative velocity's rms where
        the body's motion is known, else the wheel's, over the rate."""
        v = (self.wheel_vel_mps if self.body_vel_mps is None
             else self.body_vel_mps - self.wheel_vel_mps)
        return float(np.sqrt(np.mean(np.square(v)))) / float(self.sample_rate_hz)

    def segment(self, start_s: float | None = None, end_s: float | None = None) -> GreyBoxData:
        """The samples with ``start_s <= t < end_s`` (times from this data's first sample).

        Parameters
        ----------
        start_s, end_s : float or None
            Start and end [s] from the first sample (None: the beginning, the end).

        Returns
        -------
        GreyBoxData
            A copy of the stretch; its ``start_s`` and ``name`` say where it was cut.

        Raises
        ------
        InsufficientDataError
            Fewer than 2 samples in the stretch.
        """
        fs = self.sample_rate_hz
        i0 = 0 if start_s is None else max(0, int(round(start_s * fs)))
        i1 = self.n_samples if end_s is None else min(self.n_samples, int(round(end_s * fs)))
        if i1 - i0 < 2:
            raise InsufficientDataError(f"segment {start_s}-{end_s} s of {self.name!r} holds "
                                        f"fewer than 2 samples; choose a longer segment")

        def cut(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[i0:i1].copy()

        return replace(self, wheel_disp_m=cut(self.wheel_disp_m),
                       wheel_vel_mps=cut(self.wheel_vel_mps),
                       body_accel_mps2=cut(self.body_accel_mps2),
                       body_disp_m=cut(self.body_disp_m), body_vel_mps=cut(self.body_vel_mps),
                       disturbance_basis=cut(self.disturbance_basis),
                       start_s=self.start_s + i0 / fs,
                       name=f"{self.name}[{(self.start_s + i0 / fs):.1f}-"
                            f"{(self.start_s + i1 / fs):.1f} s]")

    def split(self, fit_fraction: float = 0.75) -> tuple[GreyBoxData, GreyBoxData]:
        """(first ``fit_fraction`` of the record, the rest) for fit and validation.

        Parameters
        ----------
        fit_fraction : float
            Share of the duration used for the fit, in (0, 1).

        Returns
        -------
        (GreyBoxData, GreyBoxData)

        Raises
        ------
        FieldDiagError
            ``fit_fraction`` outside (0, 1).
        """
        if not 0.0 < fit_fraction < 1.0:
            raise FieldDiagError(f"fit_fraction={fit_fraction} must be in (0, 1)")
        cut = self.duration_s * fit_fraction
        return self.segment(None, cut), self.segment(cut, None)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_accelerations(
        cls,
        wheel_accel_mps2: np.ndarray,
        body_accel_mps2: np.ndarray,
        sample_rate_hz: float,
        *,
        band_hz: tuple[float, float] | None = None,
        added_mass_kg: float = 0.0,
        name: str = "",
        start_s: float = 0.0,
    ) -> GreyBoxData:
        """Integrate two accelerometer readings (g, bias and drift included) into fit data.

        Both channels go through the same band-limited frequency-domain integration
        (:func:`fielddiag.dsp.integrate_pair`), so the measured body acceleration is limited
        by the same filter as the wheel motion that drives the model.

        Parameters
        ----------
        wheel_accel_mps2, body_accel_mps2 : ndarray
            Wheel and body accelerometer readings [m/s^2], equal lengths.
        sample_rate_hz : float
            Sample rate [Hz].
        band_hz : (float, float) or None
            Valid band [Hz]; None chooses it with :func:`default_band_hz`.
        added_mass_kg : float
            Mass added on the body for this drive [kg].
        name : str
            Name in messages and results.
        start_s : float
            Session time of the first sample [s].

        Returns
        -------
        GreyBoxData
            Wheel displacement [m] and velocity [m/s], body acceleration [m/s^2], displacement
            and velocity, all band-limited alike.

        Raises
        ------
        FieldDiagError
            Readings of different lengths, holding NaN or inf, or that cannot be integrated.
        InsufficientDataError
            The record is shorter than 4 periods of the lower band edge.
        """
        from fielddiag import dsp

        wheel = np.asarray(wheel_accel_mps2, float)
        body = np.asarray(body_accel_mps2, float)
        if wheel.size != body.size:
            raise FieldDiagError("wheel and body readings must have the same number of samples")
        if band_hz is None:
            band_hz = default_band_hz(sample_rate_hz, wheel.size)
        min_n = int(4.0 * sample_rate_hz / band_hz[0])
        if wheel.size < min_n:
            raise InsufficientDataError(
                f"{name or 'recording'}: {wheel.size / sample_rate_hz:.1f} s is too short for "
                f"a fit down to {band_hz[0]:g} Hz; record at least {min_n / sample_rate_hz:.0f} s"
            )
        if not (np.all(np.isfinite(wheel)) and np.all(np.isfinite(body))):
            raise FieldDiagError(f"{name or 'recording'}: readings hold NaN or inf; cut them out")
        try:
            w, b = dsp.integrate_pair(wheel, body, sample_rate_hz, band_hz)
        except ValueError as exc:
            raise FieldDiagError(f"cannot integrate {name or 'recording'}: {exc}") from None
        return cls(sample_rate_hz=w.sample_rate_hz, wheel_disp_m=w.displacement_m,
                   wheel_vel_mps=w.velocity_mps, body_accel_mps2=b.acceleration_mps2,
                   added_mass_kg=float(added_mass_kg), name=name, body_disp_m=b.displacement_m,
                   body_vel_mps=b.velocity_mps, band_hz=(float(band_hz[0]), float(band_hz[1])),
                   start_s=start_s)

    @classmethod
    def from_drive(cls, drive: Any, *, truth: bool = False,
                   band_hz: tuple[float, float] | None = None, name: str = "") -> GreyBoxData:
        """Fit data from a :class:`fielddiag.sim.SimulatedDrive`.

        Parameters
        ----------
        drive : SimulatedDrive
            A simulated drive (its readings in m/s^2 and true states in m, m/s).
        truth : bool
            True: the simulator's true wheel motion and body acceleration, full band
            ("perfect data"). False: the accelerometer readings, integrated like a recording.
        band_hz : (float, float) or None
            Band of the integration [Hz] when ``truth`` is False (None: :func:`default_band_hz`).
        name : str
            Name in messages and results (default ``sim seed <seed>``).

        Returns
        -------
        GreyBoxData
        """
        name = name or f"sim seed {drive.seed}"
        if truth:
            return cls(sample_rate_hz=drive.sample_rate_hz, wheel_disp_m=drive.wheel_disp_m,
                       wheel_vel_mps=drive.wheel_vel_mps,
                       body_accel_mps2=drive.body_acc_true_mps2,
                       added_mass_kg=drive.added_mass_kg, name=name,
                       body_disp_m=drive.body_disp_m, body_vel_mps=drive.body_vel_mps)
        return cls.from_accelerations(drive.wheel_accel_mps2, drive.body_accel_mps2,
                                      drive.sample_rate_hz, band_hz=band_hz,
                                      added_mass_kg=drive.added_mass_kg, name=name)

    @classmethod
    def from_session(cls, path: str | os.PathLike, *, start_s: float | None = None,
                     end_s: float | None = None, band_hz: tuple[float, float] | None = None,
                     added_mass_kg: float | None = None) -> GreyBoxData:
        """Fit data from a session file (read by :func:`fielddiag.drive.read_corner_drive`).

        Parameters
        ----------
        path : str or PathLike
            The session (channels with roles ``wheel`` and ``body``).
        start_s, end_s : float or None
            The stretch to fit (session time [s]); it must be free of gaps.
        band_hz : (float, float) or None
            Valid band [Hz]; None chooses it with :func:`default_band_hz`.
        added_mass_kg : float or None
            Overrides the session's ``added_mass_kg`` attribute [kg].

        Returns
        -------
        GreyBoxData

        Raises
        ------
        ChannelNotFoundError, InsufficientDataError, SessionError
            As :func:`~fielddiag.drive.read_corner_drive` (``require_continuous``).
        """
        from fielddiag.drive import read_corner_drive

        d = read_corner_drive(path, start_s=start_s, end_s=end_s, added_mass_kg=added_mass_kg,
                              require_continuous=True, purpose="the fit",
                              gap_advice="fit a stretch without gaps with --start/--end")
        return cls.from_accelerations(d.wheel_accel_mps2, d.body_accel_mps2, d.sample_rate_hz,
                                      band_hz=band_hz, added_mass_kg=d.added_mass_kg,
                                      name=d.name, start_s=d.start_s)


def default_band_hz(sample_rate_hz: float, n_samples: int | None = None) -> tuple[float, float]:
    """Band for the fit when none is given: 0.5 Hz (or 8 cycles of the record) to 30 Hz.

    It spans the body bounce (~1-2 Hz) and the wheel hop (~10-15 Hz) of a car corner,
    keeps twice-integrated accelerometer noise and drift out below 0.5 Hz, and stays below
    the anti-alias filter of any DAQ sampling at 100 Hz or more.

    Parameters
    ----------
    sample_rate_hz : float
        Sample rate [Hz]; the upper edge is at most 0.3 of it.
    n_samples : int or None
        Length of the record; the lower edge is at least 8 cycles of it.

    Returns
    -------
    (float, float)
        ``(low_hz, high_hz)``.

    Raises
    ------
    InsufficientDataError
        The record is too short or too slowly sampled to leave a band of two octaves.
    """
    lo = 0.5
    if n_samples:
        lo = max(lo, 8.0 * sample_rate_hz / n_samples)
    hi = min(30.0, 0.3 * sample_rate_hz)
    if hi <= lo * 4:
        raise InsufficientDataError(
            f"a recording at {sample_rate_hz:g} Hz of {n_samples} samples leaves no band for "
            "the fit; record longer and at 100 Hz or more")
    return lo, hi


