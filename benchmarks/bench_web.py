"""Dashboard benchmarks: time to first plot of a long session, live-view latency, memory.

Usage::

    python benchmarks/bench_web.py [--dtype int32|int16|float64] [--live-seconds 10]

Method
------
1. **Session.** A 1 h recording of 8 channels at 2 kHz (57.6 M samples) is written with
   :class:`fielddiag.session.SessionWriter` in 10 s blocks, time-stamped like a recording
   (``time_base="timestamps"``), raw samples as DAQ counts of ``--dtype`` with a
   calibration scale (int32 is what the virtual DAQ sends).
2. **Server.** ``fielddiag serve`` runs as a subprocess on a free port (so its memory is
   its own); headless Chromium (Debian's chromium + chromium-driver, through Selenium)
   is the client.
3. **Time to first plot**: from asking the browser for ``/session?path=...`` until every
   one of the 8 plots holds its points in ECharts (polled every 10 ms in the page) --
   the first open (the server reads the whole hour: min/max preselection block by block,
   then LTTB to 2000 points per channel) and a second open (overview cached). The
   server-side read alone is timed in-process too. The OS page cache holds the file (it
   was just written); a cold disk adds its read time (the file size / disk speed).
4. **Zoom**: a zoom to 60 s in the middle of the hour, from the ``dataZoom`` action in the
   browser until the status line reports the new window.
5. **Server memory** (VmRSS and peak VmHWM from /proc) before any page, with the 1 h
   session open, and after the zooms.
6. **Live latency**: a recording from the virtual DAQ (500 Hz, real serial driver on a
   pty) and virtual ECU is started on the live page; for each frame the browser draws
   (ECharts ``finished`` with a new newest sample) the page notes
   ``now - (t0 + t_newest)``: wall-clock time minus the session time of the newest sample
   drawn (both clocks are this machine's). This is an upper bound of "sample arrived ->
   drawn": it includes the DAQ's own framing (100 frames/s, up to 10 ms). Also reported:
   frames drawn per second.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fielddiag.channels import ChannelSpec, SessionMetadata
from fielddiag.session import SessionWriter

FS_HZ = 2000.0
N_CH = 8
DURATION_S = 3600.0
BLOCK_S = 10.0

CHART_SERIES_JS = """
const el = document.querySelector(arguments[0]);
if (!el) return null;
const comp = getElement(el.id.slice(1));
if (!comp || !comp.chart) return null;
const o = comp.chart.getOption();
if (!o || !o.series) return null;
return o.series.map(s => (s.data || []).length);
"""


def write_big_session(path: Path, dtype: str) -> float:
    """The 1 h x 8 ch x 2 kHz session; returns the seconds it took."""
    scale = 1e-4 if dtype.startswith("int") else 1.0
    chans = [ChannelSpec(f"ch{i}", role=("wheel", "body")[i] if i < 2 else "acceleration",
                         dtype=dtype, scale=scale) for i in range(N_CH)]
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    n_block = int(BLOCK_S * FS_HZ)
    with SessionWriter(path, SessionMetadata(vehicle="bench", corner="front-left"), chans,
                       sample_rate_hz=FS_HZ, time_base="timestamps") as w:
        for k in range(int(DURATION_S / BLOCK_S)):
            t = (k * n_block + np.arange(n_block)) / FS_HZ
            x = (np.sin(2 * np.pi * 1.3 * t)[:, None] * np.arange(1, N_CH + 1)
                 + rng.normal(0.0, 0.3, (n_block, N_CH)))
            if k == 180:
                x[1234, 3] = 40.0  # one spike that must stay visible
            if dtype.startswith("int"):
                x = np.round(x / scale)
            w.append_daq(x.astype(dtype), t)
    return time.perf_counter() - t0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def rss_mb(pid: int) -> tuple[float, float]:
    """(VmRSS, VmHWM) of a process in MB."""
    vals = {}
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith(("VmRSS:", "VmHWM:")):
                k, v = line.split(":")
                vals[k] = float(v.split()[0]) / 1024.0
    return vals["VmRSS"], vals["VmHWM"]


def start_server(root: Path) -> tuple[subprocess.Popen, str]:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTEST_", "NICEGUI_"))}
    proc = subprocess.Popen([sys.executable, "-m", "fielddiag.cli", "serve", "--root",
                             str(root), "--port", str(port)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return proc, f"http://127.0.0.1:{port}"
        except OSError:
            time.sleep(0.1)
    proc.kill()
    raise RuntimeError("server did not start")


def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--window-size=1400,1000"):
        opts.add_argument(flag)
    return webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=opts)


def time_to_first_plot(d, url: str, n_series: int) -> float:
    d.get("about:blank")
    t0 = time.perf_counter()
    d.get(url)
    while time.perf_counter() - t0 < 60:
        s = d.execute_script(CHART_SERIES_JS, ".fd-session-chart")
        if s and len(s) == n_series and all(n > 0 for n in s):
            return time.perf_counter() - t0
        time.sleep(0.01)
    raise RuntimeError("the plot did not appear within 60 s")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dtype", default="int32", choices=("int16", "int32", "float64"))
    ap.add_argument("--live-seconds", type=float, default=10.0)
    ap.add_argument("--dump-live", metavar="FILE", help="save every live frame's latency")
    args = ap.parse_args()
    if not shutil.which("chromedriver"):
        print("needs chromium and chromium-driver (apt-get install chromium chromium-driver)")
        return 1

    work = Path(tempfile.mkdtemp(prefix="fielddiag-bench-web-"))
    root = work / "root"
    root.mkdir()
    big = root / "hour.h5"
    try:
        secs = write_big_session(big, args.dtype)
        print(f"session: 1 h x {N_CH} channels x {FS_HZ:g} Hz ({args.dtype}, time-stamped), "
              f"{big.stat().st_size / 1e6:.0f} MB, written in {secs:.1f} s")

        from fielddiag.downsample import PlotSource

        t0 = time.perf_counter()
        with PlotSource(big) as src:
            trs = src.traces()
        server_read = time.perf_counter() - t0
        spike = max(trs[3].values)
        print(f"server-side overview (read 57.6 M samples, min/max + LTTB to 2000 points per "
              f"channel): {server_read:.2f} s; spike kept: {spike:.1f} (true 40.0)")

        proc, base = start_server(root)
        d = browser()
        try:
            d.get(base + "/")  # load the app's scripts once, like a person would
            time.sleep(1.0)
            rss0, _ = rss_mb(proc.pid)
            url = base + "/session?path=hour.h5"
            first = time_to_first_plot(d, url, N_CH)
            rss1, hwm1 = rss_mb(proc.pid)
            second = time_to_first_plot(d, url, N_CH)
            print(f"time to first plot, 1 h x 8 ch x 2 kHz: first open {first:.2f} s, "
                  f"again (overview cached) {second:.2f} s   [goal < 1.5 s]")

            zooms = []
            for start, end in ((50.0, 50 + 100 / 60), (20.0, 20 + 100 / 60), (80.0, 81.0)):
                lo = DURATION_S * start / 100
                t0 = time.perf_counter()
                d.execute_script(
                    """const el = document.querySelector('.fd-session-chart');
                    getElement(el.id.slice(1)).chart.dispatchAction(
                        {type: 'dataZoom', start: arguments[0], end: arguments[1]});""",
                    start, end)
                want = f"{lo:.3f}"
                while time.perf_counter() - t0 < 30:
                    if want in d.find_element("tag name", "body").text:
                        break
                    time.sleep(0.01)
                zooms.append(time.perf_counter() - t0)
            rss2, hwm2 = rss_mb(proc.pid)
            print("zoom to a 36-60 s window (re-read at full detail, redrawn): "
                  + ", ".join(f"{z * 1000:.0f} ms" for z in zooms))
            print(f"server memory: {rss0:.0f} MB before, {rss1:.0f} MB with the 1 h session "
                  f"open (peak {hwm1:.0f} MB), {rss2:.0f} MB after zooming (peak {hwm2:.0f} MB)")

            # live latency
            d.get(base + "/live")
            time.sleep(1.0)
            btn = d.find_element("xpath", "//button[contains(normalize-space(.), 'Start')]")
            btn.click()
            t0 = time.perf_counter()
            while time.perf_counter() - t0 < 60:
                s = d.execute_script(CHART_SERIES_JS, ".fd-live-chart")
                if s and len(s) >= 2 and s[0] > 50:
                    break
                time.sleep(0.05)
            time.sleep(2.0)
            d.execute_script("""window.__lat = []; window.__last = null;
                const el = document.querySelector('.fd-live-chart');
                const t0 = parseFloat(el.getAttribute('data-t0-unix'));
                const c = getElement(el.id.slice(1)).chart;
                c.on('finished', () => {
                    const s = c.getOption().series[0].data;
                    const x = s[s.length - 1][0];
                    if (x === window.__last) return;
                    window.__last = x;
                    window.__lat.push([performance.now(), Date.now() / 1000 - t0 - x]);
                });""")
            time.sleep(args.live_seconds)
            lat = np.array(d.execute_script("return window.__lat"))
            d.find_element("xpath", "//button[contains(normalize-space(.), 'Stop')]").click()
            time.sleep(1.0)
            ms = lat[:, 1] * 1000
            if args.dump_live:
                np.savetxt(args.dump_live, lat, header="browser_ms latency_s")
            fps = (len(lat) - 1) / ((lat[-1, 0] - lat[0, 0]) / 1000)
            print(f"live view, {len(lat)} frames over {args.live_seconds:g} s ({fps:.1f} "
                  f"frames/s): newest sample time -> drawn: median {np.median(ms):.0f} ms, "
                  f"95 % {np.percentile(ms, 95):.0f} ms, max {ms.max():.0f} ms   "
                  "[goal < 200 ms]")
        finally:
            d.quit()
            proc.terminate()
            proc.wait(10)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    load = os.getloadavg()
    print(f"machine: {os.cpu_count()} CPUs, load average {load[0]:.1f} during the run")
    return 0


if __name__ == "__main__":
    sys.exit(main())
