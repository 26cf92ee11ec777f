"""drivers.can_decode: the one CAN decoder of live recording and import.

A small DBC written here holds every case: signals in km/h, deg, deg/s, g, %, rpm and mph;
a multiplexed message; a CAN FD message with an extended identifier that a classic message
shares the number of. Expected values are the raw values times the DBC scale times the
exact SI factor (1/3.6, 0.44704, pi/180, 2 pi/60, 9.80665).
"""

from __future__ import annotations

import math
import time
import uuid

import can
import cantools
import numpy as np
import pytest

from drivers import open_source
from drivers.base import SessionClock
from drivers.can_decode import (
    FD_LENGTHS,
    BusTable,
    CanDecoder,
    Dbc,
    buses_named,
    default_signals,
    load_dbc,
    messages_to_frames,
    payload_lengths,
    presence,
    resolve_signals,
)
from fielddiag.errors import DbcError
from fielddiag.io.canlog import import_can_log
from fielddiag.session import (
    CAN_FLAG_ERROR,
    CAN_FLAG_EXTENDED,
    CAN_FLAG_FD,
    CAN_FLAG_REMOTE,
    CAN_FRAME_DTYPE,
    SessionReader,
)

DBC_TEXT = """VERSION ""

NS_ :

BS_:

BU_: ECU

BO_ 100 KIN: 8 ECU
 SG_ SPEED : 0|16@1+ (0.01,0) [0|655.35] "km/h" ECU
 SG_ STEER : 16|16@1- (0.1,0) [-3276.8|3276.7] "deg" ECU
 SG_ YAW : 32|16@1- (0.01,0) [-327.68|327.67] "deg/s" ECU
 SG_ ACC : 48|8@1- (0.01,0) [-1.28|1.27] "g" ECU
 SG_ LOAD : 56|8@1+ (0.5,0) [0|127.5] "%" ECU

BO_ 101 ENGINE: 2 ECU
 SG_ RPM : 0|16@1+ (1,0) [0|65535] "rpm" ECU

BO_ 200 MUXED: 8 ECU
 SG_ MUX M : 0|8@1+ (1,0) [0|255] "" ECU
 SG_ TEMP m0 : 8|16@1- (0.1,0) [-3276.8|3276.7] "degC" ECU
 SG_ SPEED m1 : 8|16@1+ (0.01,0) [0|655.35] "mph" ECU

BO_ 2147484160 FD_WHEELS: 12 ECU
 SG_ COUNTER : 0|8@1+ (1,0) [0|255] "" ECU
 SG_ WHEEL_SPEED_FL : 64|16@1+ (0.01,0) [0|655.35] "mph" ECU
 SG_ WHEEL_SPEED_FR : 80|16@1+ (0.01,0) [0|655.35] "mph" ECU

BO_ 512 STD_512: 8 ECU
 SG_ COUNTER : 0|8@1+ (1,0) [0|255] "" ECU

BA_DEF_ BO_ "VFrameFormat" ENUM "StandardCAN","ExtendedCAN","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","reserved","StandardCAN_FD","ExtendedCAN_FD";
BA_DEF_DEF_ "VFrameFormat" "StandardCAN";
BA_ "VFrameFormat" BO_ 2147484160 15;
"""  # noqa: E501

MPH = 0.44704


@pytest.fixture(scope="module")
def db():
    return cantools.database.load_string(DBC_TEXT, database_format="dbc", strict=False)


@pytest.fixture()
def dbc_file(tmp_path):
    p = tmp_path / "test.dbc"
    p.write_text(DBC_TEXT)
    return p


def _le(value: int, n: int) -> bytes:
    return int(value).to_bytes(n, "little", signed=value < 0)


def _kin(speed_raw: int, steer_raw: int, yaw_raw: int, acc_raw: int, load_raw: int) -> bytes:
    return (_le(speed_raw, 2) + _le(steer_raw, 2) + _le(yaw_raw, 2) + _le(acc_raw, 1)
            + _le(load_raw, 1))


def _std(ident: int, **kw) -> can.Message:
    """A frame with a standard (11-bit) identifier (python-can's default is extended)."""
    return can.Message(arbitration_id=ident, is_extended_id=False, **kw)


def _frames(msgs: list[can.Message], bus: int | list[int] = 0) -> np.ndarray:
    return messages_to_frames(msgs, [float(i) for i in range(len(msgs))], bus)


# ------------------------------------------------------------------------------- lengths
def test_fd_length_table_and_payload_lengths_follow_python_can():
    assert FD_LENGTHS.tolist() == list(can.util.CAN_FD_DLC)
    f = np.zeros(65 + 16, dtype=CAN_FRAME_DTYPE)
    f["dlc"][:65] = np.arange(65)
    f["flags"][:65] = CAN_FLAG_FD
    f["dlc"][65:] = np.arange(16)  # classic: DLC codes 9..15 still mean 8 bytes
    got = payload_lengths(f).tolist()
    # CAN FD: the byte count rounded up to a length the bus can carry (10 -> 12, 33 -> 48)
    assert got[:65] == [can.util.dlc2len(can.util.len2dlc(n)) for n in range(65)]
    assert got[10] == 12 and got[33] == 48 and got[64] == 64
    assert got[65:] == [min(n, 8) for n in range(16)]


def test_can_fd_frame_decodes_and_a_classic_frame_too_short_counts_an_error(db):
    payload10 = bytes([7]) + bytes(7) + _le(6000, 2)  # 10 bytes: FL = 60.00 mph, FR padding
    fd = can.Message(arbitration_id=0x200, is_extended_id=True, is_fd=True, data=payload10)
    classic = can.Message(arbitration_id=0x200, is_extended_id=True, data=payload10[:8])
    frames = _frames([fd, classic])
    assert frames["dlc"].tolist() == [10, 8]
    assert payload_lengths(frames).tolist() == [12, 8]
    dec = CanDecoder(resolve_signals(db, ["FD_WHEELS.COUNTER", "WHEEL_SPEED_FL",
                                          "WHEEL_SPEED_FR"]))
    out = dec.decode(frames)
    # the FD frame: 10 bytes travel as 12, the last two zero-padded
    assert out["WHEEL_SPEED_FL"][1].tolist() == [60.00 * MPH]
    assert out["WHEEL_SPEED_FR"][1].tolist() == [0.0]
    # the 8-byte classic frame holds the counter but not the wheel speeds: one decode error
    assert out["COUNTER"][1].tolist() == [7.0, 7.0]
    assert out["WHEEL_SPEED_FL"][0].tolist() == [0.0]
    assert dec.errors == 1 and dec.decoded_frames == 2
    # a signal that fits in the short frame is no error
    only_counter = CanDecoder(resolve_signals(db, ["FD_WHEELS.COUNTER"]))
    only_counter.decode(frames)
    assert only_counter.errors == 0


# ------------------------------------------------------------------------------- units
def test_units_are_converted_to_si_with_exact_factors(db):
    msgs = [
        _std(100, data=_kin(10000, -900, 1800, -50, 150)),
        _std(101, data=_le(3000, 2)),
    ]
    dec = CanDecoder(resolve_signals(db, ["KIN.SPEED", "STEER", "YAW", "ACC", "LOAD", "RPM"]))
    units = {s.name: s.unit for s in dec.specs}
    assert units == {"SPEED": "m/s", "STEER": "rad", "YAW": "rad/s", "ACC": "m/s2",
                     "LOAD": "%", "RPM": "rad/s"}
    out = {k: v[1][0] for k, v in dec.decode(_frames(msgs)).items()}
    assert out["SPEED"] == pytest.approx(100.0 / 3.6, rel=1e-15)  # 100 km/h = 27.78 m/s
    assert out["STEER"] == pytest.approx(-math.pi / 2, rel=1e-15)  # -90 deg
    assert out["YAW"] == pytest.approx(0.1 * math.pi, rel=1e-15)  # 18 deg/s
    assert out["ACC"] == pytest.approx(-0.5 * 9.80665, rel=1e-15)  # -0.5 g
    assert out["LOAD"] == 75.0  # % is no unit to convert
    assert out["RPM"] == pytest.approx(100 * math.pi, rel=1e-15)  # 3000 rpm = 314.16 rad/s
    assert dec.errors == 0


# ------------------------------------------------------------------------------- frames
def test_multiplexed_signals_only_where_their_multiplexer_says(db):
    msgs = [_std(200, data=bytes([mux]) + _le(raw, 2) + bytes(5))
            for mux, raw in ((0, -245), (1, 5000), (0, 300), (2, 1), (1, 10000))]
    dec = CanDecoder(resolve_signals(db, ["MUXED.SPEED", "TEMP", "MUX", "KIN.SPEED"]))
    assert [s.name for s in dec.specs] == ["MUXED.SPEED", "TEMP", "MUX", "KIN.SPEED"]
    out = dec.decode(_frames(msgs))
    assert out["TEMP"][0].tolist() == [0.0, 2.0]  # the frames with MUX 0
    assert out["TEMP"][1] == pytest.approx([-24.5, 30.0], rel=1e-12)  # degC: kept
    assert out["MUXED.SPEED"][0].tolist() == [1.0, 4.0]
    assert out["MUXED.SPEED"][1] == pytest.approx([50 * MPH, 100 * MPH], rel=1e-15)
    assert out["MUX"][0].tolist() == [0.0, 1.0, 2.0, 4.0]
    assert out["MUX"][1].tolist() == [0.0, 1.0, 0.0, 1.0]
    assert "KIN.SPEED" not in out  # no KIN frame in this batch
    # MUX 2 is a multiplexer value the DBC does not define: cantools rejects the frame,
    # which counts one decode error and gives no sample of any signal
    assert dec.errors == 1 and dec.decoded_frames == 4


def test_unknown_extended_remote_and_error_frames(db):
    msgs = [
        _std(0x300, data=bytes(8)),  # in no DBC message
        _std(0x200, data=bytes([1]) + bytes(7)),  # STD_512
        can.Message(arbitration_id=0x200, is_extended_id=True, is_fd=True,
                    data=bytes([2]) + bytes(11)),  # FD_WHEELS
        _std(0x200, is_remote_frame=True, dlc=8),
        _std(0x200, is_error_frame=True, data=bytes(8)),
        can.Message(arbitration_id=0x12345, is_extended_id=True, data=bytes(8)),
    ]
    frames = _frames(msgs)
    flags = frames["flags"].tolist()
    assert flags[2] & (CAN_FLAG_EXTENDED | CAN_FLAG_FD) == CAN_FLAG_EXTENDED | CAN_FLAG_FD
    assert flags[3] & CAN_FLAG_REMOTE and flags[4] & CAN_FLAG_ERROR
    dec = CanDecoder(resolve_signals(db, ["std=STD_512.COUNTER", "fd=FD_WHEELS.COUNTER"]))
    out = dec.decode(frames)
    # the same number 0x200: standard and extended identifiers are different messages;
    # remote and error frames are kept raw but never decoded; unknown ids are ignored
    assert out["std"][0].tolist() == [1.0] and out["std"][1].tolist() == [1.0]
    assert out["fd"][0].tolist() == [2.0] and out["fd"][1].tolist() == [2.0]
    assert dec.errors == 0 and dec.decoded_frames == 2


def test_a_dbc_bound_to_a_bus_decodes_only_that_bus(db):
    msgs = [_std(101, data=_le(rpm, 2)) for rpm in (1000, 2000, 3000)]
    frames = _frames(msgs, bus=[0, 1, 1])
    table = BusTable()
    assert [table.index(c) for c in ("can0", "can1")] == [0, 1]
    bound = Dbc(db, "test.dbc", buses_named("can1", table.names))
    (t, v), = CanDecoder(resolve_signals(bound, ["RPM"])).decode(frames).values()
    assert t.tolist() == [1.0, 2.0]
    assert v == pytest.approx([2000 * math.pi / 30, 3000 * math.pi / 30], rel=1e-15)


def test_bus_table_numbers_channels_by_their_trailing_digits():
    t = BusTable()
    assert [t.index(c) for c in ("can1", "vcan0", "radar", 5, "can1", None)] == [1, 0, 2, 5, 1, 3]
    assert t.names == {1: "can1", 0: "vcan0", 2: "radar", 5: "5", 3: ""}
    assert buses_named(None, t.names) is None
    assert buses_named("radar", t.names) == {2} and buses_named("7", t.names) == {7}


# ------------------------------------------------------------------------------- names
def test_signal_names_roles_and_errors(db):
    c = resolve_signals(db, ["vehicle_speed=KIN.SPEED", "ENGINE.RPM"])
    assert [(x.name, x.role, x.spec.message) for x in c] == [
        ("vehicle_speed", "speed", "KIN"), ("RPM", "other", "ENGINE")]
    # without an alias: the first signal with a vehicle speed name and a speed unit
    assert [x.role for x in resolve_signals(db, ["RPM", "KIN.SPEED"])] == ["other", "speed"]
    assert [x.role for x in resolve_signals(db, ["RPM"], speed_signal="RPM")] == ["speed"]
    # asked twice under one name: kept once
    assert [x.name for x in resolve_signals(db, ["RPM", "ENGINE.RPM"])] == ["RPM"]
    cases = [
        (["SPED"], "signal 'SPED' is not in the DBC; did you mean SPEED"),
        (["SPEED"], r"defined in several messages \(KIN.SPEED, MUXED.SPEED\)"),
        (["KIN.NOPE"], "message KIN has no signal 'NOPE'; it has SPEED, STEER"),
        (["x=KIN.SPEED", "x=RPM"], "signals named twice: x; give them aliases"),
    ]
    for requests, message in cases:
        with pytest.raises(DbcError, match=message):
            resolve_signals(db, requests)
    with pytest.raises(DbcError, match="speed signal 'v' is not among the decoded signals"):
        resolve_signals(db, ["RPM"], speed_signal="v")


def test_ambiguous_name_is_taken_from_the_message_present_and_defaults(db):
    frames = _frames([_std(200, data=bytes([1, 0x10, 0x27]) + bytes(5)),
                      can.Message(arbitration_id=0x200, is_extended_id=True, is_fd=True,
                                  data=bytes(12))])
    (c,) = resolve_signals(db, ["SPEED"], present=presence(frames))
    assert (c.name, c.spec.message, c.role, c.spec.unit) == ("SPEED", "MUXED", "speed", "m/s")
    # defaults: the vehicle speed, then the wheel speeds, of messages that occur
    d = default_signals(Dbc(db), presence(frames))
    assert [(x.name, x.role) for x in d] == [
        ("SPEED", "speed"), ("WHEEL_SPEED_FL", "other"), ("WHEEL_SPEED_FR", "other")]


def test_load_dbc_errors(tmp_path):
    with pytest.raises(DbcError, match="DBC file .*none.dbc not found"):
        load_dbc(tmp_path / "none.dbc")
    bad = tmp_path / "bad.dbc"
    bad.write_text("BO_ this is not a DBC\n")
    with pytest.raises(DbcError, match="bad.dbc: not a readable CAN database"):
        load_dbc(bad)


# ------------------------------------------------------------------- the two paths agree
def _fd_and_classic_traffic() -> list[can.Message]:
    msgs = []
    for k in range(40):
        msgs.append(_std(100,
                                data=_kin(2000 + 37 * k, -10 * k, 5 * k - 90, k - 20, k)))
        msgs.append(can.Message(arbitration_id=0x200, is_extended_id=True, is_fd=True,
                                bitrate_switch=True,
                                data=bytes([k]) + bytes(7) + _le(3000 + k, 2)))  # 10 bytes
        msgs.append(_std(200, data=bytes([k % 2]) + _le(100 * k, 2)
                                + bytes(5)))
    return msgs


def test_live_bus_and_log_import_store_identical_signals_fd_included(tmp_path, dbc_file):
    """The same classic and CAN FD frames, sent on a python-can virtual bus to a live
    source and written to a candump log then imported: the same names, units and values."""
    msgs = _fd_and_classic_traffic()
    requests = ["KIN.SPEED", "STEER", "YAW", "ACC", "WHEEL_SPEED_FL", "WHEEL_SPEED_FR",
                "TEMP", "mux_speed=MUXED.SPEED"]
    channel = f"test-{uuid.uuid4().hex[:8]}"
    tx = can.Bus(interface="virtual", channel=channel)
    url = f"can://virtual/{channel}?dbc={dbc_file}&" + "&".join(f"signal={r}" for r in requests)
    src = open_source(url)
    src.open()
    src.start(SessionClock())
    for m in msgs:
        tx.send(m)
    live: dict[str, list[np.ndarray]] = {}
    deadline = time.monotonic() + 10.0
    while src.frames_received < len(msgs) and time.monotonic() < deadline:
        b = src.read(0.05)
        for k, (_, v) in (b.signals if b else {}).items():
            live.setdefault(k, []).append(v)
    src.close()
    tx.shutdown()
    assert src.frames_received == len(msgs)

    log = tmp_path / "same.log"
    with can.Logger(str(log)) as out:
        for i, m in enumerate(msgs):
            m.timestamp, m.channel = 1_700_000_000.0 + 0.001 * i, "can0"
            out.on_message_received(m)
    imported = tmp_path / "imported.h5"
    import_can_log(log, imported, dbc=[dbc_file], signals=requests)
    with SessionReader(imported) as s:
        specs = {x.name: (x.unit, x.message, x.role) for x in s.signals}
        values = {x.name: s.signal(x.name)[1] for x in s.signals}
        assert s.counters["can_decode_errors"] == 0
    assert specs == {x.name: (x.unit, x.message, x.role) for x in src.signals}
    assert set(live) == set(values)
    for name, v in values.items():
        got = np.concatenate(live[name])
        assert got.dtype == v.dtype and got.tobytes() == v.tobytes(), name
    assert values["WHEEL_SPEED_FL"][5] == pytest.approx(30.05 * MPH, rel=1e-15)
    assert values["YAW"][0] == pytest.approx(math.radians(-0.9), rel=1e-12)
    assert src.counters()["can_decode_errors"] == 0


def test_the_examples_in_the_docstrings_hold():
    import doctest

    from drivers import can_decode

    result = doctest.testmod(can_decode)
    assert result.attempted >= 10 and result.failed == 0
