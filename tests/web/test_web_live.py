"""Live recording page with the real virtual devices (pty DAQ, python-can virtual bus)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import numpy as np
import pytest

from fielddiag.session import SessionReader
from fielddiag.web.services import recorder_backend

pytestmark = [
    pytest.mark.anyio,
    pytest.mark.skipif(not recorder_backend().available, reason=recorder_backend().reason),
]


def _the(user, marker: str):
    found = user.find(marker=marker).elements
    assert len(found) == 1
    return next(iter(found))


async def _until(user, predicate, timeout_s: float = 20.0) -> None:
    deadline = asyncio.get_running_loop().time() + timeout_s
    while asyncio.get_running_loop().time() < deadline:
        with user:
            if predicate():
                return
        await asyncio.sleep(0.05)
    raise AssertionError("condition not met in time")


async def test_record_live_mark_an_event_and_stop(dashboard_user, sessions_root: Path) -> None:
    user = dashboard_user
    await user.open("/live")
    _the(user, "live-path").set_value("recordings/test-live.h5")
    _the(user, "live-vehicle").set_value("bench car")
    user.find(marker="live-start").click()
    chart = _the(user, "live-chart")
    frames = _the(user, "counter-frames_received")
    await _until(user, lambda: frames.text not in ("-", "0") and int(frames.text) >= 100)
    assert _the(user, "live-state").text == "recording"
    # the plots show the last seconds of every channel and the CAN speed
    names = [s["name"] for s in chart.options["series"]]
    assert names == ["wheel_z", "body_z", "vehicle_speed"]
    body = np.array(chart.options["series"][1]["data"], dtype=float)
    assert body.shape[0] > 50
    # the body sensor reads g plus the ride motion
    assert 9.0 < np.median(body[:, 1]) < 10.6
    x_axis = chart.options["xAxis"][0]
    assert x_axis["max"] - x_axis["min"] == pytest.approx(10.0)
    assert _the(user, "counter-frames_lost").text == "0"
    assert _the(user, "counter-crc_errors").text == "0"

    _the(user, "event-label").set_value("speed bump")
    user.find(marker="mark-event").click()
    await user.should_see("event at")
    await _until(user, lambda: "speed bump @" in _the(user, "events-shown").text)
    # the on-line estimator reports per-parameter observability with advice: one row per
    # parameter of the estimator, each with its name, its state and a bar
    await _until(user, lambda: _has(user, "observability-advice"), timeout_s=10)
    advice = _the(user, "observability-advice").text
    assert advice.startswith(("enough data", "waiting for data")) or "keep driving" in advice \
        or "not yet observable" in advice
    estimated = user.state.live["recording"].observability()["parameters"]
    with user:
        rows = _elements("observability-param")
        assert len(rows) == len(estimated) >= 2
        for row, param in zip(rows, estimated, strict=True):
            (name,) = _inside(row, "observability-name")
            (state,) = _inside(row, "observability-state")
            (bar,) = _inside(row, "observability-bar")
            assert name.text == param["label"]
            assert state.text in ("ok", "converging", "not observable")
            assert 0.0 <= bar.value <= 1.0

    user.find(marker="live-stop").click()
    await _until(user, lambda: _has(user, "live-saved-link"), timeout_s=20)
    path = sessions_root / "recordings" / "test-live.h5"
    with SessionReader(path) as s:
        assert s.closed_cleanly
        assert s.metadata.vehicle == "bench car"
        assert [e.label for e in s.events] == ["speed bump"]
        assert s.n_samples > 500
        assert s.counters["frames_received"] >= 100
        assert "vehicle_speed" in [sig.name for sig in s.signals]
    assert user.state.live["recording"].running is False


def _elements(marker: str) -> list:
    """Elements with ``marker`` on the page, in page order (call inside ``with user:``)."""
    from nicegui.element_filter import ElementFilter

    return list(ElementFilter(marker=marker))


def _inside(parent, marker: str) -> list:
    from nicegui.element_filter import ElementFilter

    return list(ElementFilter(marker=marker).within(instance=parent))


async def test_virtual_daq_faults_show_in_the_counters(dashboard_user) -> None:
    """A corrupting serial link: the CRC-error and frames-lost counters go above 0."""
    user = dashboard_user
    await user.open("/live")
    _the(user, "live-path").set_value("recordings/faulty.h5")
    _the(user, "can-source").set_value("none")
    _the(user, "fault-corrupt-rate").set_value(0.002)  # ~10 % of the ~56-byte frames
    user.find(marker="live-start").click()
    crc = _the(user, "counter-crc_errors")
    lost = _the(user, "counter-frames_lost")

    def counted(label) -> int:
        return int(label.text) if label.text.isdigit() else 0

    await _until(user, lambda: counted(crc) >= 3 and counted(lost) >= 3, timeout_s=15)
    st = user.state.live["recording"].status()
    assert st["crc_errors"] >= counted(crc) and st["frames_lost"] >= counted(lost)
    user.find(marker="live-stop").click()
    await _until(user, lambda: _has(user, "live-saved-link"), timeout_s=20)


async def test_live_page_refuses_bad_fault_settings(dashboard_user) -> None:
    user = dashboard_user
    await user.open("/live")
    _the(user, "fault-corrupt-rate").set_value(0.5)
    user.find(marker="live-start").click()
    await user.should_see("byte corruption rate must be at least 0 and below 0.1")
    assert "recording" not in user.state.live


def _has(user, marker: str) -> bool:
    from nicegui.element_filter import ElementFilter

    with user:
        return len(list(ElementFilter(marker=marker))) > 0


async def test_live_page_refuses_a_path_outside_the_root(dashboard_user) -> None:
    user = dashboard_user
    await user.open("/live")
    _the(user, "live-path").set_value("../outside.h5")
    user.find(marker="live-start").click()
    await user.should_see("outside the sessions folder")
    assert "recording" not in user.state.live
