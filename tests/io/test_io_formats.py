"""The import registry: detection from contents and names, options, and dispatch."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from fielddiag.channels import SessionMetadata
from fielddiag.errors import ImportFormatError
from fielddiag.io import formats
from fielddiag.io.formats import FORMATS, detect_format, get_format, import_file
from fielddiag.session import SessionReader

DATA = Path("/work/shared/data")
LOG = DATA / "can" / "comma2k19_rav4_2018-08-02_seg40.log"
IMU = DATA / "vehicle_imu" / "comma2k19_rav4_seg40_imu.csv"


def test_every_format_has_an_importer_and_documented_options():
    assert {"csv", "fielddiag-csv", "pvs", "canlog", "mdf"} <= set(FORMATS)
    for fmt in FORMATS.values():
        module, _, func = fmt.importer.partition(":")
        if fmt.requires is None:
            assert callable(fmt.load()), fmt.name
        for opt in fmt.options:
            assert opt.cli.startswith("--") and opt.help and opt.dest
    assert [o.cli for o in FORMATS["canlog"].options] == ["--dbc", "--signal"]
    assert get_format("MF4") is FORMATS["mdf"] and get_format("candump") is FORMATS["canlog"]
    with pytest.raises(ImportFormatError, match="unknown format 'xls'; known: csv"):
        get_format("xls")


def test_detection_from_contents(tmp_path):
    cases = {
        "a.csv": "time,acc\n0,1\n",
        "b.txt": "t;x\n0;1\n",
        "c.log": "(1533226488.230547) can0 0B4#000000001D0B7A5E\n",
        "d.dat": "(0.5) vcan0 18FEF100#00\n",  # candump content wins over the name
        "e.asc": "date Mon Jan 1 00:00:00 2024\n",
        "f.csv": "timestamp,arbitration_id,extended,remote,error,dlc,data\n",
        "g.csv": "timestamp,acc_x_dashboard,acc_z_above_suspension,acc_z_below_suspension\n",
        "h.bin": "MDF     4.10    ",
        "i.mf4": "MDF     4.10    ",
    }
    expected = {"a.csv": "csv", "b.txt": "csv", "c.log": "canlog", "d.dat": "canlog",
                "e.asc": "canlog", "f.csv": "canlog", "g.csv": "pvs", "h.bin": "mdf",
                "i.mf4": "mdf"}
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        assert detect_format(tmp_path / name) == expected[name], name
    (tmp_path / "a.fielddiag.json").write_text("{}")
    assert detect_format(tmp_path / "a.csv") == "fielddiag-csv"
    (tmp_path / "x.blf").write_bytes(b"LOGG" + bytes(140))
    assert detect_format(tmp_path / "x.blf") == "canlog"
    (tmp_path / "z.xyz").write_text("hello")
    with pytest.raises(ImportFormatError, match="cannot tell the format of z.xyz.*--format"):
        detect_format(tmp_path / "z.xyz")
    (tmp_path / "broken.mf4").write_bytes(b"\0" * 64)
    with pytest.raises(ImportFormatError, match="broken.mf4: not an MDF file"):
        detect_format(tmp_path / "broken.mf4")
    with pytest.raises(ImportFormatError, match="no such file"):
        detect_format(tmp_path / "missing.csv")
    with pytest.raises(ImportFormatError, match="neither a PVS dataset"):
        detect_format(tmp_path)


@pytest.mark.skipif(not LOG.is_file(), reason="real data not available")
def test_detection_of_the_real_files():
    assert detect_format(LOG) == "canlog"
    # the comma2k19 IMU CSV goes to its own importer once fielddiag.io.vehicle_imu exists,
    # otherwise it is an ordinary CSV
    assert detect_format(IMU) == ("comma2k19" if "comma2k19" in FORMATS else "csv")


def test_import_file_dispatches_and_checks_options(tmp_path):
    src = tmp_path / "drive.csv"
    t = np.arange(400) / 200.0
    rows = ["time,acc_w,acc_b,v_kmh"] + [
        f"{ti!r},{float(np.sin(9 * ti))!r},{float(np.cos(2 * ti))!r},{36.0 + ti!r}"
        for ti in t.tolist()]
    src.write_text("\n".join(rows) + "\n")
    out = tmp_path / "s.h5"
    meta = SessionMetadata(vehicle="Golf", added_mass_kg=25.0)
    import_file(src, out, metadata=meta, roles=["wheel=acc_w", "body=acc_b", "speed=v_kmh"],
                time_column="time", speed_unit="km/h", dbc=None, signals=[])
    assert meta.extra == {}  # the caller's metadata is not modified
    with SessionReader(out) as s:
        assert s.metadata.vehicle == "Golf" and s.metadata.added_mass_kg == 25.0
        np.testing.assert_array_equal(s.read_role("wheel"), np.sin(9 * t))
        _, v = s.signal(s.signal_for_role("speed").name)
        np.testing.assert_allclose(v, (36.0 + t) / 3.6, rtol=1e-12)
    with pytest.raises(ImportFormatError, match="--dbc does not apply to format 'csv'"):
        import_file(src, tmp_path / "x.h5", dbc=["car.dbc"], time_column="time")
    with pytest.raises(ImportFormatError, match="--time COLUMN"):
        import_file(src, tmp_path / "x.h5", roles=["wheel=acc_w"])
    with pytest.raises(ImportFormatError, match="a CAN log needs a DBC file"):
        import_file(src, tmp_path / "x.h5", format="canlog")
    assert not (tmp_path / "x.h5").exists()


def test_options_from_argparse_namespace(tmp_path):
    ns = argparse.Namespace(role=["wheel=a"], time_column="t", time_unit=None, accel_unit="g",
                            speed_unit=None, dbc=None, signal=[], side=None,
                            vertical_axis=None, channel=None)
    assert formats.options_from_args("csv", ns) == {
        "roles": ["wheel=a"], "time_column": "t", "accel_unit": "g"}
    ns.dbc, ns.role, ns.time_column, ns.accel_unit = ["x.dbc"], None, None, None
    assert formats.options_from_args("canlog", ns) == {"dbc": ["x.dbc"]}
    assert formats.options_from_args("mdf", ns) == {"dbc": ["x.dbc"]}
    # an option the format does not take is passed on, and import_file names it
    opts = formats.options_from_args("pvs", ns)
    assert opts == {"dbc": ["x.dbc"]}
    with pytest.raises(ImportFormatError, match="--dbc does not apply to format 'pvs'"):
        import_file(tmp_path / "PVS 1", tmp_path / "x.h5", format="pvs", **opts)


@pytest.mark.skipif("comma2k19" not in FORMATS or not IMU.is_file(),
                    reason="fielddiag.io.vehicle_imu or the real data is not available")
def test_comma2k19_files_merge_imu_can_speed_and_gnss(tmp_path):
    """Any of the three CSVs (or their folder) gives one session with all of them."""
    assert detect_format(IMU.parent) == "comma2k19"
    out = tmp_path / "c.h5"
    import_file(IMU.parent / "comma2k19_rav4_seg40_gnss_ublox.csv", out,
                metadata=SessionMetadata(vehicle="RAV4 test"))
    with SessionReader(out) as s:
        assert s.metadata.vehicle == "RAV4 test"
        assert s.n_samples == 6256  # README: IMU rows
        assert abs(np.mean(s.read_role("body")) - 9.66) < 0.05  # README: acc_down mean -9.661
        t, v = s.signal(s.signal_for_role("speed").name)
        assert t.size == 4974 and 28.7 / 3.6 - 0.01 < v.min() < v.max() < 71.4 / 3.6 + 0.01
        gnss = [x for x in s.signals if x.source == "gnss"]
        assert gnss and all(s.signal(x.name)[0].size == 579 for x in gnss)  # 10 Hz fixes
