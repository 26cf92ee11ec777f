"""Accelerometer and DAQ channel model applied to the internal-rate true acceleration."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import signal

from fielddiag.errors import FieldDiagError
from fielddiag.sim._common import G_MPS2, check_number


@dataclass(frozen=True)
class SensorModel:
    """Accelerometer and DAQ channel: reading = acceleration + g, through this chain.

    At the internal rate: delay by ``time_offset_s``, ``gain * (a + g) + bias + drift * t``,
    causal Butterworth (order 4, cutoff ``anti_alias_cutoff_ratio * output_rate_hz``, state
    started at the first reading, i.e. the static reading: no start transient). Decimate to
    ``output_rate_hz``, then add white noise (ADC/electronics), quantise, and saturate at
    +-``clip_mps2`` (full scale of the output).

    Parameters
    ----------
    output_rate_hz : float
        Output sample rate (same for both channels of a drive).
    noise_std_mps2 : float
        Standard deviation of the white noise added after the filter.
    snr_db : float or None
        Alternative to ``noise_std_mps2``: noise std = RMS of the channel's dynamic
        acceleration (true acceleration at the output rate, times gain, mean removed)
        / 10^(snr_db / 20).
    bias_mps2, bias_drift_mps2_per_s : float
        Constant offset and linear drift (from t = 0).
    gain : float
        Scale factor on acceleration + g.
    time_offset_s : float
        Delay of this channel (positive: the reading at t shows the motion at t - offset).
        Give it on ``body_sensor`` only to emulate body/wheel misalignment.
    clip_mps2 : float or None
        Saturation of the reading (including g) at +-clip.
    quantization_step_mps2 : float or None
        ADC step; readings are rounded to multiples of it.
    anti_alias_cutoff_ratio : float
        Filter cutoff over output rate, in (0, 0.5).
    """

    output_rate_hz: float = 500.0
    noise_std_mps2: float = 0.0
    snr_db: float | None = None
    bias_mps2: float = 0.0
    bias_drift_mps2_per_s: float = 0.0
    gain: float = 1.0
    time_offset_s: float = 0.0
    clip_mps2: float | None = None
    quantization_step_mps2: float | None = None
    anti_alias_cutoff_ratio: float = 0.4

    def __post_init__(self) -> None:
        o = "SensorModel"
        check_number(o, "output_rate_hz", self.output_rate_hz, low=0.0, strict=True)
        check_number(o, "noise_std_mps2", self.noise_std_mps2, low=0.0)
        for name in ("bias_mps2", "bias_drift_mps2_per_s", "gain", "time_offset_s"):
            check_number(o, name, getattr(self, name))
        for name in ("clip_mps2", "quantization_step_mps2"):
            if getattr(self, name) is not None:
                check_number(o, name, getattr(self, name), low=0.0, strict=True)
        if self.snr_db is not None:
            check_number(o, "snr_db", self.snr_db)
            if self.noise_std_mps2 > 0:
                raise FieldDiagError("SensorModel: give noise_std_mps2 or snr_db, not both.")
        r = self.anti_alias_cutoff_ratio
        check_number(o, "anti_alias_cutoff_ratio", r)
        if not 0.0 < r < 0.5:
            raise FieldDiagError(
                f"SensorModel: anti_alias_cutoff_ratio={r!r} must be in "
                "(0, 0.5) (cutoff below the output Nyquist frequency)."
            )

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of the fields."""
        return asdict(self)


#: The default sensor (500 Hz, ideal apart from the anti-alias filter).
DEFAULT_SENSOR = SensorModel()


def _delay(x: np.ndarray, samples: float) -> np.ndarray:
    """x delayed by a (fractional) number of samples, linear interpolation, ends held."""
    whole = round(samples)
    if abs(samples - whole) > 1e-9:
        whole = math.floor(samples)
    frac = samples - whole
    idx = np.clip(np.arange(x.size) - whole, 0, x.size - 1)
    y = x[idx]
    if frac > 1e-9:
        y = (1.0 - frac) * y + frac * x[np.clip(idx - 1, 0, x.size - 1)]
    return y


def _read_sensor(
    acc: np.ndarray,
    internal_rate_hz: float,
    k: int,
    n_out: int,
    sensor: SensorModel,
    acc_out_true: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Apply the sensor chain to internal-rate true acceleration ``acc``."""
    x = acc + G_MPS2
    if sensor.time_offset_s != 0.0:
        x = _delay(x, sensor.time_offset_s * internal_rate_hz)
    x = sensor.gain * x + sensor.bias_mps2
    if sensor.bias_drift_mps2_per_s != 0.0:
        x = x + sensor.bias_drift_mps2_per_s / internal_rate_hz * np.arange(x.size)
    sos = signal.butter(
        4, sensor.anti_alias_cutoff_ratio * sensor.output_rate_hz, fs=internal_rate_hz, output="sos"
    )
    y, _ = signal.sosfilt(sos, x, zi=signal.sosfilt_zi(sos) * x[0])
    y = y[::k][:n_out]
    std = sensor.noise_std_mps2
    if sensor.snr_db is not None:
        dyn = acc_out_true - acc_out_true.mean()
        std = abs(sensor.gain) * math.sqrt(np.mean(dyn * dyn)) / 10 ** (sensor.snr_db / 20)
    if std > 0:
        y = y + rng.normal(0.0, std, y.size)
    if sensor.quantization_step_mps2 is not None:
        y = np.round(y / sensor.quantization_step_mps2) * sensor.quantization_step_mps2
    if sensor.clip_mps2 is not None:
        y = np.clip(y, -sensor.clip_mps2, sensor.clip_mps2)
    return y
