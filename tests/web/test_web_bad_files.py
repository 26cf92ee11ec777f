"""A truncated session in the dashboard's root must not block the session list (issue 14).

Before the guard, the first 2000 bytes of a session made the catalog's scan hang in h5py
for 15 minutes and more: the list never loaded. Here ``fielddiag serve`` runs as a real
subprocess and a real headless Chromium loads the list.
"""

from __future__ import annotations

import time
from pathlib import Path

from web_helpers import LiveServer


def _body(driver) -> str:
    return driver.find_element("tag name", "body").text


def _wait(fn, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        try:
            last = fn()
        except Exception as exc:  # element not there yet
            last = exc
        else:
            if last:
                return last
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}: last {last!r}")


def _rows(driver) -> dict[str, str]:
    """Session path -> status, as the table shows them."""
    heads = [h.text.replace("arrow_upward", "").strip()
             for h in driver.find_elements("css selector", "thead th")]
    i, j = heads.index("Session"), heads.index("Status")
    out = {}
    for row in driver.find_elements("css selector", "tbody tr"):
        cells = row.find_elements("tag name", "td")
        out[cells[i].text] = cells[j].text
    return out


def test_truncated_file_does_not_block_the_session_list(browser, sessions_root: Path):
    whole = (sessions_root / "car-a" / "before.h5").read_bytes()
    (sessions_root / "truncated.h5").write_bytes(whole[:2000])  # hung h5py before
    (sessions_root / "car-a" / "half-copied.h5").write_bytes(whole[: len(whole) // 2])
    server = LiveServer(sessions_root)
    try:
        t0 = time.monotonic()
        browser.get(server.url + "/")
        _wait(lambda: "4 of 4 sessions" in _body(browser), 30.0, "the session list")
        load_s = time.monotonic() - t0
        rows = _wait(lambda: (r := _rows(browser)) and len(r) == 4 and r, 5.0, "4 rows")
        assert rows == {"car-a/after.h5": "ok", "car-a/before.h5": "ok",
                        "car-a/half-copied.h5": "unreadable", "truncated.h5": "unreadable"}
        body = _body(browser)
        assert body.count("test car") == 2  # the good sessions with their header
        # page load, the first scan (starts the reader worker) and two probes
        print(f"session list with 2 bad files loaded in {load_s:.2f} s")
        assert load_s < 10.0, load_s

        # the bad file's own page says why, in one line, and the server still answers
        browser.get(server.url + "/session?path=truncated.h5")
        err = _wait(lambda: browser.find_element("css selector", ".text-negative").text,
                    10.0, "the error of the truncated file")
        assert err == (f"{(sessions_root / 'truncated.h5').resolve()} is not a complete "
                       f"fielddiag session (truncated at 2000 of {len(whole)} bytes): copy it "
                       "again from the original")
        browser.get(server.url + "/session?path=car-a/before.h5")
        _wait(lambda: "samples per channel" in _body(browser), 20.0, "the good session's plot")
    finally:
        browser.get("about:blank")
        server.stop()
    assert "Traceback" not in server.output()
