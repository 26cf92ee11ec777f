"""PVS import, tested on a synthetic drive written in the dataset's exact public layout.

No real PVS file is available on this machine (see shared/data/README.md, section 3). The
column names and order below are the published ones (the authors' pre-processing notebook
in jefmenegazzo/MPU-9250-and-GPS-Raw-Data-Pre-Processing, and repositories that load the
files), written here independently of fielddiag.io.pvs: timestamp in UNIX s rounded to
0.01 s, accelerations in m/s2 with gravity, gyro in deg/s, magnetometer in uT, GPS fix
(1 Hz) repeated on every 100 Hz row, one-hot labels in dataset_labels.csv.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fielddiag.channels import SessionMetadata
from fielddiag.errors import ImportFormatError
from fielddiag.io.formats import detect_format, import_file
from fielddiag.io.pvs import import_pvs
from fielddiag.session import SessionReader

G = 9.80665
POS = ("dashboard", "above_suspension", "below_suspension")
MPU_COLS = (
    ["timestamp"]
    + [f"acc_{a}_{p}" for p in POS for a in "xyz"]
    + [f"gyro_{a}_{p}" for p in POS for a in "xyz"]
    + [f"mag_{a}_{p}" for p in POS[:2] for a in "xyz"]
    + [f"temp_{p}" for p in POS]
)
GPS_COLS = ["timestamp_gps", "latitude", "longitude", "speed"]
LABEL_COLS = ["paved_road", "unpaved_road", "dirt_road", "cobblestone_road", "asphalt_road",
              "no_speed_bump", "speed_bump_asphalt", "speed_bump_cobblestone",
              "good_road_left", "regular_road_left", "bad_road_left",
              "good_road_right", "regular_road_right", "bad_road_right"]
T0 = 1577218812.37  # 2019-12-24, the day PVS 1 was driven
N = 3000  # 30 s at 100 Hz


def _write(path: Path, header: list[str], columns: list[np.ndarray]) -> None:
    rows = np.column_stack(columns).tolist()
    with open(path, "w") as fh:
        fh.write(",".join(header) + "\n")
        fh.writelines(",".join(map(repr, r)) + "\n" for r in rows)


def make_drive(folder: Path, *, upside_down_below=True, y_vertical_above=False) -> dict:
    """A 30 s drive: the wheel sees a 12 Hz road + bumps, the body a filtered 1.3 Hz motion."""
    rng = np.random.default_rng(7)
    folder.mkdir(parents=True, exist_ok=True)
    ts = np.round(T0 + np.arange(N) * 0.01, 2)
    t = ts - ts[0]
    wheel = 3.0 * np.sin(2 * np.pi * 12 * t) + rng.normal(0, 0.5, N)
    body = 0.8 * np.sin(2 * np.pi * 1.3 * t) + rng.normal(0, 0.05, N)
    cols = {"timestamp": ts}
    for p in POS:
        for a in "xyz":
            cols[f"acc_{a}_{p}"] = rng.normal(0, 0.3, N)
            cols[f"gyro_{a}_{p}"] = rng.normal(0, 2.0, N)
        cols[f"temp_{p}"] = 30 + rng.normal(0, 0.1, N)
    for p in POS[:2]:
        for a in "xyz":
            cols[f"mag_{a}_{p}"] = 40 + rng.normal(0, 1.0, N)
    cols["acc_z_dashboard"] = G + rng.normal(0, 0.1, N)
    cols["acc_z_below_suspension"] = -(G + wheel) if upside_down_below else G + wheel
    if y_vertical_above:
        cols["acc_y_above_suspension"] = G + body
    else:
        cols["acc_z_above_suspension"] = G + body
    fix_t = np.round(T0 - 0.4 + np.arange(32), 3)  # 1 Hz fixes, first one before the MPU data
    fix_v = 8 + 4 * np.sin(np.arange(32) / 5)
    held = np.searchsorted(fix_t, ts, side="right") - 1
    gps = [fix_t[held], -27.59 + held * 1e-5, -48.54 + held * 1e-5, fix_v[held]]
    _write(folder / "dataset_gps_mpu_left.csv", MPU_COLS + GPS_COLS,
           [cols[c] for c in MPU_COLS] + gps)
    labels = np.zeros((N, len(LABEL_COLS)))
    li = {c: i for i, c in enumerate(LABEL_COLS)}
    labels[:, li["paved_road"]] = 1
    labels[t < 10, li["asphalt_road"]] = 1
    labels[t >= 10, li["cobblestone_road"]] = 1
    labels[:, li["no_speed_bump"]] = 1
    bump = (t >= 5.0) & (t < 5.5)
    labels[bump, li["speed_bump_asphalt"]], labels[bump, li["no_speed_bump"]] = 1, 0
    labels[:, li["good_road_left"]] = 1
    labels[:, li["bad_road_right"]] = 1
    _write(folder / "dataset_labels.csv", LABEL_COLS, list(labels.T))
    return {"ts": ts, "wheel": wheel, "body": body, "cols": cols, "fix_t": fix_t,
            "fix_v": fix_v, "held": held}


def test_pvs_file_imports_with_roles_units_speed_and_labels(tmp_path):
    d = make_drive(tmp_path / "PVS 1")
    src = tmp_path / "PVS 1" / "dataset_gps_mpu_left.csv"
    assert detect_format(src) == "pvs" and detect_format(tmp_path / "PVS 1") == "pvs"
    out = tmp_path / "pvs.h5"
    import_file(src, out, metadata=SessionMetadata(vehicle="VW Saveiro"))
    with SessionReader(out) as s:
        assert s.time_base == "uniform" and s.sample_rate_hz == pytest.approx(100.0, rel=1e-9)
        assert s.n_samples == N
        assert s.metadata.t0_unix_s == pytest.approx(T0, abs=1e-6)
        assert s.metadata.corner == "front-left" and s.metadata.vehicle == "VW Saveiro"
        wheel, body = s.channel_for_role("wheel"), s.channel_for_role("body")
        assert (wheel.name, body.name) == ("wheel_z", "body_z")
        # accelerometers read a + g, up positive: the upside-down module gets scale -1
        assert wheel.scale == -1.0 and body.scale == 1.0 and wheel.unit == "m/s2"
        np.testing.assert_array_equal(s.read("wheel_z"), G + d["wheel"])
        np.testing.assert_array_equal(s.read_raw("wheel_z"), d["cols"]["acc_z_below_suspension"])
        np.testing.assert_array_equal(s.read("body_z"), G + d["body"])
        assert abs(np.mean(s.read_role("wheel")) - G) < 0.05
        gyro = s.channel("gyro_x_below_suspension")
        assert gyro.unit == "rad/s"
        np.testing.assert_allclose(s.read(gyro.name), np.radians(d["cols"][gyro.name]),
                                   rtol=1e-15)
        assert s.channel("mag_z_above_suspension").unit == "T"
        np.testing.assert_allclose(s.read("mag_z_above_suspension"),
                                   d["cols"]["mag_z_above_suspension"] * 1e-6, rtol=1e-15)
        assert s.channel("temp_dashboard").unit == "degC"
        names = {c.name for c in s.channels}
        assert "acc_z_below_suspension" not in names and "acc_x_below_suspension" in names
        assert len(names) == len(MPU_COLS) - 1  # every sensor column, two renamed to roles
        # the GPS fixes at 1 Hz on their own time stamps, not the 100 Hz repetitions
        ts_speed, v = s.signal(s.signal_for_role("speed").name)
        fixes = np.unique(d["held"])
        np.testing.assert_allclose(ts_speed, d["fix_t"][fixes] - T0, atol=1e-6)
        np.testing.assert_array_equal(v, d["fix_v"][fixes])
        assert s.signal_spec("vehicle_speed").unit == "m/s"
        assert np.median(np.diff(ts_speed)) == pytest.approx(1.0, abs=1e-6)
        _, lat = s.signal("latitude_deg")
        assert lat.size == fixes.size
        events = {(round(e.time_s, 2), e.label) for e in s.events}
    assert {(0.0, "asphalt_road"), (10.0, "cobblestone_road"), (5.0, "speed_bump_asphalt"),
            (0.0, "good_road_left")} <= events
    assert not any(lbl.endswith("_right") or lbl == "no_speed_bump" for _, lbl in events)


def test_folder_right_side_and_auto_vertical_axis(tmp_path):
    folder = tmp_path / "PVS 2"
    d = make_drive(folder, upside_down_below=False, y_vertical_above=True)
    (folder / "dataset_gps_mpu_left.csv").rename(folder / "dataset_gps_mpu_right.csv")
    out = tmp_path / "r.h5"
    import_pvs(folder, out, side="right")
    with SessionReader(out) as s:
        assert s.metadata.corner == "front-right"
        assert s.metadata.extra["pvs_vertical_axis"] == {"below_suspension": "z",
                                                         "above_suspension": "y"}
        np.testing.assert_array_equal(s.read("body_z"), G + d["body"])
        assert "acc_z_above_suspension" in {c.name for c in s.channels}
        events = {e.label for e in s.events}
    assert "bad_road_right" in events and "good_road_left" not in events
    with pytest.raises(ImportFormatError, match="--vertical-axis must be"):
        import_pvs(folder, tmp_path / "x.h5", side="right", vertical_axis="w")
    with pytest.raises(ImportFormatError, match="no dataset_gps_mpu_left.csv"):
        import_pvs(folder, tmp_path / "x.h5")


def test_mpu_file_takes_speed_from_dataset_gps(tmp_path):
    folder = tmp_path / "PVS 3"
    d = make_drive(folder)
    src = folder / "dataset_gps_mpu_left.csv"
    lines = src.read_text().splitlines()
    k = len(MPU_COLS)
    (folder / "dataset_mpu_left.csv").write_text(
        "\n".join(",".join(ln.split(",")[:k]) for ln in lines) + "\n")
    src.unlink()
    gps_header = ["timestamp", "latitude", "longitude", "elevation", "accuracy", "bearing",
                  "speed_meters_per_second", "satellites"]
    n_fix = d["fix_t"].size
    _write(folder / "dataset_gps.csv", gps_header,
           [d["fix_t"], np.full(n_fix, -27.59), np.full(n_fix, -48.54), np.full(n_fix, 20.0),
            np.full(n_fix, 3.0), np.zeros(n_fix), d["fix_v"], np.full(n_fix, 9.0)])
    out = tmp_path / "m.h5"
    import_file(folder, out)
    with SessionReader(out) as s:
        t, v = s.signal("vehicle_speed")
        assert s.signal_spec("vehicle_speed").message == "dataset_gps.csv"
        assert s.metadata.extra["imported_from"] == "dataset_mpu_left.csv"
    np.testing.assert_allclose(t, d["fix_t"] - T0, atol=1e-6)
    np.testing.assert_array_equal(v, d["fix_v"])


def test_pvs_errors(tmp_path):
    folder = tmp_path / "PVS 4"
    make_drive(folder)
    src = folder / "dataset_gps_mpu_left.csv"
    with pytest.raises(ImportFormatError, match="holds the left side, but --side right"):
        import_pvs(src, tmp_path / "x.h5", side="right")
    lines = src.read_text().splitlines()
    header = lines[0].replace("acc_z_above_suspension", "acc_z_body")
    bad = tmp_path / "dataset_gps_mpu_left.csv"
    bad.write_text("\n".join([header, *lines[1:]]) + "\n")
    with pytest.raises(ImportFormatError, match="no column 'acc_z_above_suspension'"):
        import_pvs(bad, tmp_path / "x.h5")
    row = lines[200].split(",")
    row[9] = "abc"  # acc_z_below_suspension
    lines[200] = ",".join(row)
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(ImportFormatError, match=r"row 201, column 'acc_z_below_suspension'"):
        import_pvs(bad, tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()
    assert not [p for p in tmp_path.iterdir() if "partial" in p.name]
