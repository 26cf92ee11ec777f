"""The same real CAN frames, recorded live and imported, give byte-identical signals.

The first 10 s of the powertrain bus (can0) of the real RAV4 log (comma2k19, see
shared/data/README.md) are:

* replayed in real time on a python-can virtual bus and recorded by the command a
  technician runs, ``fielddiag record --can can://virtual/...?dbc=... --signal ...``
  (in this process: a virtual bus does not leave it), and
* written to a candump log (the original lines) and imported with
  ``fielddiag import FILE --dbc ... --signal ...``.

Both sessions must hold the same signals (names, SI units, messages, roles) with the same
values, byte for byte and in the same order, from the same raw frames. Only the time stamps
differ, by the transport: live frames carry the time the virtual bus sent them (wall clock
on the session clock), imported frames the log's own time from its first frame; each
session's ``t0_unix_s`` maps its times back to the wall clock, which the test checks too.
"""

from __future__ import annotations

import signal
import threading
import time
import uuid

import can
import numpy as np
import pytest
from _real_data import CAN_LOG, PT_DBC

from fielddiag import cli
from fielddiag.session import SessionReader

SLICE_S = 10.0
#: One signal for each unit conversion: km/h, m/s^2, deg/s, deg, rpm.
SIGNALS = [
    "SPEED",
    "WHEEL_SPEED_FL",
    "WHEEL_SPEED_FR",
    "WHEEL_SPEED_RL",
    "WHEEL_SPEED_RR",
    "ACCEL_X",
    "YAW_RATE",
    "STEER_ANGLE_SENSOR.STEER_ANGLE",
    "RPM",
]
UNITS = {"SPEED": "m/s", "WHEEL_SPEED_FL": "m/s", "WHEEL_SPEED_FR": "m/s",
         "WHEEL_SPEED_RL": "m/s", "WHEEL_SPEED_RR": "m/s", "ACCEL_X": "m/s2",
         "YAW_RATE": "rad/s", "STEER_ANGLE": "rad", "RPM": "rad/s"}

pytestmark = pytest.mark.skipif(not CAN_LOG.is_file(), reason=f"real CAN log not at {CAN_LOG}")


def _slice(path) -> list[str]:
    """The can0 lines of the first SLICE_S seconds of the log, as written."""
    out: list[str] = []
    with open(CAN_LOG) as fh:
        t0 = None
        for line in fh:
            t = float(line[1 : line.index(")")])
            t0 = t if t0 is None else t0
            if t - t0 > SLICE_S:
                break
            if " can0 " in line:
                out.append(line)
    path.write_text("".join(out))
    return out


class _Replay(threading.Thread):
    """Sends the slice on a virtual bus at the log's pace once the recorder listens."""

    def __init__(self, channel: str, msgs: list[can.Message], ready) -> None:
        super().__init__(daemon=True, name="replay")
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.msgs, self.ready = msgs, ready
        self.sent: list[tuple[float, float]] = []  # wall clock just before / after each send
        self.start_unix_s = 0.0
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            deadline = time.monotonic() + 20.0
            while not self.ready() and time.monotonic() < deadline:
                time.sleep(0.01)
            log_t0 = self.msgs[0].timestamp
            self.start_unix_s = start = time.time()
            for m in self.msgs:
                wait = start + (m.timestamp - log_t0) - time.time()
                if wait > 0:
                    time.sleep(wait)
                before = time.time()
                self.bus.send(m)
                self.sent.append((before, time.time()))
        except BaseException as exc:  # reported by the test
            self.error = exc
        finally:
            self.bus.shutdown()


def _read(path):
    with SessionReader(path) as s:
        specs = {x.name: x for x in s.signals if x.source == "can"}
        sig = {name: s.signal(name) for name in specs}
        return specs, sig, s.can_frames(), s.counters, s.metadata


def test_live_recording_and_import_of_the_same_frames_store_identical_signals(tmp_path):
    log = tmp_path / "rav4_can0_10s.log"
    lines = _slice(log)
    msgs = list(can.LogReader(str(log)))
    assert len(msgs) == len(lines) > 8000  # about 900 frames/s on the powertrain bus

    # live: `fielddiag record --can can://virtual/CH?dbc=PT --signal ...`
    live_path = tmp_path / "live.h5"
    channel = f"rav4-{uuid.uuid4().hex[:8]}"
    replay = _Replay(channel, msgs, ready=live_path.exists)  # the file: the bus is open
    replay.start()
    sig_args = [a for name in SIGNALS for a in ("--signal", name)]
    sigterm = signal.getsignal(signal.SIGTERM)
    try:
        rc = cli.main(["record", "--can", f"can://virtual/{channel}?dbc={PT_DBC}", *sig_args,
                       "-o", str(live_path), "--duration", str(SLICE_S + 3.0), "--quiet",
                       "--no-online"])
    finally:
        signal.signal(signal.SIGTERM, sigterm)  # `record` catches SIGTERM; give it back
    replay.join(10.0)
    assert rc == 0 and replay.error is None and len(replay.sent) == len(msgs)

    # import: `fielddiag import FILE --dbc PT --signal ...`
    imported_path = tmp_path / "imported.h5"
    assert cli.main(["import", str(log), "-o", str(imported_path), "--dbc", str(PT_DBC),
                     *sig_args]) == 0

    live_specs, live, live_frames, live_counters, live_meta = _read(live_path)
    imp_specs, imp, imp_frames, imp_counters, imp_meta = _read(imported_path)

    # the same raw frames, in the same order
    assert live_counters["can_frames_received"] == imp_counters["can_frames_received"] == len(msgs)
    for field in ("arbitration_id", "bus", "flags", "dlc", "data"):
        assert np.array_equal(live_frames[field], imp_frames[field]), field
    assert live_counters["can_decode_errors"] == imp_counters["can_decode_errors"] == 0

    # the same signals: names, SI units, messages, roles; values byte for byte, in order
    assert sorted(live_specs) == sorted(imp_specs) == sorted(UNITS)
    assert live_specs == imp_specs
    assert {n: s.unit for n, s in live_specs.items()} == UNITS
    assert live_specs["SPEED"].role == "speed"
    for name in UNITS:
        (tl, vl), (_, vi) = live[name], imp[name]
        assert vl.dtype == vi.dtype == np.float64, name
        assert vl.tobytes() == vi.tobytes(), name
        assert tl.size == vl.size and np.all(np.diff(tl) >= 0), name
    # SPEED at 41 Hz; the drive accelerates from 29 to 73 km/h in these 10 s (README)
    _, v = imp["SPEED"]
    assert v.size == pytest.approx(41.45 * SLICE_S, abs=5)
    assert v[0] == pytest.approx(29.38 / 3.6, abs=0.01 / 3.6)
    assert v.max() == pytest.approx(73.05 / 3.6, abs=0.5 / 3.6)

    # time stamps: live = when the virtual bus sent each frame, on the session clock;
    # imported = the log's own time from its first frame; t0_unix_s maps both to wall clock
    sent = np.array(replay.sent)
    t_live = live_frames["time_s"] + live_meta.t0_unix_s
    assert np.all(t_live >= sent[:, 0] - 1e-6) and np.all(t_live <= sent[:, 1] + 1e-6)
    t_log = np.array([m.timestamp for m in msgs])
    assert np.max(np.abs(imp_frames["time_s"] + imp_meta.t0_unix_s - t_log)) < 2e-6
    # the signal time stamps are those of the frames that carried them
    speed_rows = (live_frames["arbitration_id"] == 0xB4)
    assert np.array_equal(live["SPEED"][0], live_frames["time_s"][speed_rows])
    assert np.array_equal(imp["SPEED"][0], imp_frames["time_s"][speed_rows])
    # how late the replay sent each frame against the log's pace (scheduling, not data)
    late_s = sent[:, 0] - (replay.start_unix_s + (t_log - t_log[0]))
    print(f"\nreplay lateness vs the log's pace: median {1e3 * np.median(late_s):.2f} ms, "
          f"95th percentile {1e3 * np.percentile(late_s, 95):.2f} ms, max "
          f"{1e3 * late_s.max():.1f} ms over {len(msgs)} frames")
