"""Import a body-mounted vehicle IMU with CAN speeds (the comma2k19 RAV4 excerpt) as a session.

Files (``/work/shared/data/vehicle_imu``, see its README):

* IMU CSV: ``t_boot_s, t_utc_s, acc_forward_mps2, acc_right_mps2, acc_down_mps2,
  gyro_forward_radps, gyro_right_radps, gyro_down_radps`` (specific force, gravity
  included; axes forward/right/down of the comma EON on the windscreen, so a sprung-mass
  measurement).
* CAN speed CSV: ``t_boot_s, t_utc_s, speed_mps, wheel_fl_mps, wheel_fr_mps,
  wheel_rl_mps, wheel_rr_mps``.
* GNSS CSV (optional): ``t_boot_s, latitude_deg, longitude_deg, speed_mps, utc_ms,
  altitude_m, bearing_deg``.

The session gets ``body_z`` (role ``body``, vertical, **up** positive: ``-acc_down``, so
it reads +g at rest as fielddiag's convention asks), the other IMU axes as role ``other``
in the file's own axes, the device's own (irregular) time stamps kept as the time base
(session time 0 = first IMU sample, ``t0_unix_s`` from ``t_utc_s``), the CAN vehicle speed
as the signal ``vehicle_speed`` (role ``speed``), the four wheel speeds, and the GNSS fix
signals when given. There is no wheel-side accelerometer in this data set, so the
session has no ``wheel`` channel.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from fielddiag.channels import ChannelSpec, SessionMetadata, SignalSpec
from fielddiag.errors import ImportFormatError
from fielddiag.session import write_session

IMU_COLUMNS = ("t_boot_s", "t_utc_s", "acc_forward_mps2", "acc_right_mps2", "acc_down_mps2",
               "gyro_forward_radps", "gyro_right_radps", "gyro_down_radps")
SPEED_COLUMNS = ("t_boot_s", "speed_mps", "wheel_fl_mps", "wheel_fr_mps", "wheel_rl_mps",
                 "wheel_rr_mps")
GNSS_COLUMNS = ("t_boot_s", "latitude_deg", "longitude_deg", "speed_mps", "altitude_m")

SENSOR = "comma EON IMU on the windscreen (comma2k19)"


def _read_csv(path: str | os.PathLike, required: tuple[str, ...]) -> dict[str, np.ndarray]:
    p = Path(path)
    if not p.is_file():
        raise ImportFormatError(f"{p} does not exist; give the path of the CSV file")
    try:
        header = p.open().readline().strip().split(",")
    except (OSError, UnicodeDecodeError) as exc:
        raise ImportFormatError(f"{p} cannot be read as text ({exc})") from None
    missing = [c for c in required if c not in header]
    if missing:
        raise ImportFormatError(
            f"{p.name} lacks the column(s) {', '.join(missing)} (it has {', '.join(header)}); "
            f"expected the comma2k19 export with columns {', '.join(required)}")
    try:
        data = np.genfromtxt(p, delimiter=",", skip_header=1, dtype=float, invalid_raise=True)
    except ValueError as exc:
        raise ImportFormatError(f"{p.name}: a row does not parse as numbers ({exc})") from None
    data = np.atleast_2d(data)
    if data.shape[0] < 2 or data.shape[1] != len(header):
        raise ImportFormatError(f"{p.name} holds {data.shape[0]} rows of {data.shape[1]} values "
                                f"for {len(header)} columns; it needs at least 2 full rows")
    cols = {name: data[:, i] for i, name in enumerate(header)}
    bad = [c for c in required if not np.all(np.isfinite(cols[c]))]
    if bad:
        raise ImportFormatError(f"{p.name}: column(s) {', '.join(bad)} hold empty or non-numeric"
                                " values; repair or cut those rows")
    t = cols["t_boot_s"]
    if np.any(np.diff(t) <= 0):
        i = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
        raise ImportFormatError(f"{p.name}: t_boot_s does not increase at data row {i + 1} "
                                f"({t[i - 1]!r} then {t[i]!r}); sort the file by time")
    return cols


def import_vehicle_imu(
    imu_csv: str | os.PathLike,
    speed_csv: str | os.PathLike | None,
    out_path: str | os.PathLike,
    *,
    gnss_csv: str | os.PathLike | None = None,
    vehicle: str = "Toyota RAV4 2018 (comma2k19, dongle b0c9d2329ad1606b)",
    overwrite: bool = False,
    metadata: SessionMetadata | None = None,
) -> Path:
    """Write the IMU (and CAN speed, GNSS) CSVs as a session; return its path.

    Parameters
    ----------
    imu_csv : path
        IMU CSV (columns :data:`IMU_COLUMNS`).
    speed_csv : path or None
        CAN speed CSV (columns :data:`SPEED_COLUMNS`), on the same ``t_boot_s`` clock.
    out_path : path
        Session file to create (atomically).
    gnss_csv : path or None
        u-blox GNSS CSV (columns :data:`GNSS_COLUMNS`).
    vehicle : str
        Stored in the metadata.
    overwrite : bool
        Replace an existing session file.
    metadata : SessionMetadata or None
        Fields the user set (corner, operator, added mass, notes) override the defaults.

    Raises
    ------
    ImportFormatError
        A file is missing, lacks a column, holds non-numbers, or time goes backwards.
    """
    imu = _read_csv(imu_csv, IMU_COLUMNS)
    t_boot0 = float(imu["t_boot_s"][0])
    t = imu["t_boot_s"] - t_boot0
    dt = np.diff(t)
    rate = 1.0 / float(np.median(dt))
    channels = [
        ChannelSpec("body_z", "m/s2", role="body", axis="z", sensor=SENSOR + ", -acc_down"),
        ChannelSpec("imu_acc_forward", "m/s2", role="other", axis="forward", sensor=SENSOR),
        ChannelSpec("imu_acc_right", "m/s2", role="other", axis="right", sensor=SENSOR),
        ChannelSpec("imu_gyro_forward", "rad/s", role="other", axis="forward", sensor=SENSOR),
        ChannelSpec("imu_gyro_right", "rad/s", role="other", axis="right", sensor=SENSOR),
        ChannelSpec("imu_gyro_down", "rad/s", role="other", axis="down", sensor=SENSOR),
    ]
    samples = np.column_stack([-imu["acc_down_mps2"], imu["acc_forward_mps2"],
                               imu["acc_right_mps2"], imu["gyro_forward_radps"],
                               imu["gyro_right_radps"], imu["gyro_down_radps"]])
    signals: dict[SignalSpec, tuple[np.ndarray, np.ndarray]] = {}
    if speed_csv is not None:
        sp = _read_csv(speed_csv, SPEED_COLUMNS)
        ts = sp["t_boot_s"] - t_boot0
        signals[SignalSpec("vehicle_speed", "m/s", "can", "SPEED", role="speed")] = (
            ts, sp["speed_mps"])
        for key, name in (("wheel_fl_mps", "wheel_speed_fl"), ("wheel_fr_mps", "wheel_speed_fr"),
                          ("wheel_rl_mps", "wheel_speed_rl"), ("wheel_rr_mps", "wheel_speed_rr")):
            signals[SignalSpec(name, "m/s", "can", "WHEEL_SPEEDS")] = (ts, sp[key])
    if gnss_csv is not None:
        g = _read_csv(gnss_csv, GNSS_COLUMNS)
        tg = g["t_boot_s"] - t_boot0
        for key, name, unit in (("speed_mps", "gnss_speed", "m/s"),
                                ("latitude_deg", "gnss_latitude", "deg"),
                                ("longitude_deg", "gnss_longitude", "deg"),
                                ("altitude_m", "gnss_altitude", "m")):
            signals[SignalSpec(name, unit, "gnss", "u-blox")] = (tg, g[key])
    t0_unix = float(imu["t_utc_s"][0]) if np.isfinite(imu["t_utc_s"][0]) else 0.0
    meta = SessionMetadata(
        vehicle=vehicle, corner="body (windscreen)", operator="comma.ai (comma2k19 dataset)",
        notes=("Real drive, 280 highway, California, 2018-08-02. Body-mounted IMU only: no "
               "wheel-side accelerometer. body_z = -acc_down (up positive, includes +g). "
               "Device time stamps kept (irregular). Source: commaai/comma2k19, MIT licence."),
        t0_unix_s=t0_unix,
        extra={"source": "comma2k19 Example_1/b0c9d2329ad1606b|2018-08-02--08-34-47/40",
               "licence": "MIT", "imu_t_boot0_s": t_boot0,
               "timing_jitter_fraction": float(np.std(dt) / np.median(dt)),
               "imported_from": [str(Path(p).name) for p in (imu_csv, speed_csv, gnss_csv)
                                 if p is not None]})
    if metadata is not None:
        for key in ("corner", "operator", "notes"):
            if getattr(metadata, key):
                setattr(meta, key, getattr(metadata, key))
        meta.added_mass_kg = metadata.added_mass_kg
    return write_session(out_path, meta, channels, samples, sample_rate_hz=rate, time_s=t,
                         signals=signals, overwrite=overwrite)
