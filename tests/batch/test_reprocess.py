"""``fielddiag reprocess``: pairing, a real dask LocalCluster with 2 workers, corrupt sessions
failing alone, resuming, the SQLite catalog the dashboard reads, a worker killed mid-task."""

from __future__ import annotations

import json
import os
import sqlite3
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from fielddiag.batch.discover import SessionHeader, find_sessions, pair_sessions, read_manifest
from fielddiag.batch.reprocess import plan
from fielddiag.batch.runner import run_jobs
from fielddiag.batch.store import CATALOG_NAME, BatchCatalog
from fielddiag.batch.task import PairJob, PairOutcome, StepOutcome
from fielddiag.catalog import Catalog
from fielddiag.channels import ChannelSpec, SessionMetadata
from fielddiag.cli import main
from fielddiag.errors import FieldDiagError
from fielddiag.session import write_session
from fielddiag.sim import QuarterCarParams, simulate_pair
from fielddiag.simio import drive_to_session

CAR = QuarterCarParams()  # body 380 kg, 24 kN/m, 1800 Ns/m


# ------------------------------------------------------------------------------ pairing
def _h(name: str, vehicle: str, corner: str, mass: float, created: str) -> SessionHeader:
    return SessionHeader(Path(f"/fleet/{name}.h5"), vehicle, corner, mass, created)


def test_pairs_by_vehicle_corner_and_nearest_time():
    headers = [
        _h("a0_morning", "car-a", "front-left", 0, "2026-05-01T08:00:00+00:00"),
        _h("a0_noon", "car-a", "front-left", 0, "2026-05-01T12:00:00+00:00"),
        _h("a50_noon", "car-a", "front-left", 50, "2026-05-01T12:30:00+00:00"),
        _h("arl0", "car-a", "rear-left", 0, "2026-05-01T12:00:00+00:00"),
        _h("arl40", "car-a", "rear-left", 40, "2026-05-01T12:20:00+00:00"),
        _h("b0", "car-b", "front-left", 0, "2026-05-01T12:00:00+00:00"),
        _h("b60_next_week", "car-b", "front-left", 60, "2026-05-08T12:00:00+00:00"),
        _h("c75", "car-c", "front-left", 75, "2026-05-01T12:00:00+00:00"),
        SessionHeader(Path("/fleet/broken.h5"), error="cannot read the session header: x"),
    ]
    p = pair_sessions(headers, max_apart_h=24)
    pairs = {(x.before.stem, x.after.stem): x.added_mass_kg for x in p.pairs}
    # the after drive goes with the before drive closest in time, same vehicle and corner
    assert pairs == {("a0_noon", "a50_noon"): 50.0, ("arl0", "arl40"): 40.0}
    why = {path.stem: reason for path, reason in p.unpaired}
    assert "more than 24 h apart" in why["b60_next_week"]
    assert "no drive without added mass" in why["c75"]
    assert why["a0_morning"] == "no drive with added mass to pair it with"
    assert [path.stem for path, _ in p.unreadable] == ["broken"]
    # without recording times only a single candidate can be chosen
    undated = [_h("u0", "van", "fl", 0, ""), _h("u1", "van", "fl", 0, ""),
               _h("u50", "van", "fl", 50, ""), _h("w0", "bus", "fl", 0, ""),
               _h("w50", "bus", "fl", 50, "")]
    p2 = pair_sessions(undated)
    assert [(x.before.stem, x.after.stem) for x in p2.pairs] == [("w0", "w50")]
    assert "no recording times" in dict((q.stem, r) for q, r in p2.unpaired)["u50"]
    # a wider window pairs the week-apart drives
    wide = pair_sessions(headers, max_apart_h=24 * 8)
    assert ("b0", "b60_next_week") in {(x.before.stem, x.after.stem) for x in wide.pairs}


def test_added_mass_is_the_difference_of_the_sessions_masses():
    headers = [_h("base20", "v", "fl", 20, "2026-05-01T12:00:00"),
               _h("plus70", "v", "fl", 70, "2026-05-01T12:10:00")]
    # a session with 20 kg of ballast already is an "after" drive: nothing to pair it with
    assert pair_sessions(headers).pairs == []
    headers[0] = _h("base0", "v", "fl", 0, "2026-05-01T12:00:00")
    assert pair_sessions(headers).pairs[0].added_mass_kg == 70.0


def _tiny_session(path: Path, vehicle: str, mass: float) -> Path:
    x = np.zeros((100, 2))
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_session(path, SessionMetadata(vehicle=vehicle, corner="fl", added_mass_kg=mass),
                         [ChannelSpec("wheel_z", role="wheel"), ChannelSpec("body_z", role="body")],
                         x, sample_rate_hz=100.0)


def test_manifest_pairs_as_it_says_and_rejects_bad_rows(tmp_path):
    a = _tiny_session(tmp_path / "x" / "one.h5", "van", 0)
    b = _tiny_session(tmp_path / "x" / "two.h5", "other van", 0)  # metadata would not pair
    c = _tiny_session(tmp_path / "x" / "three.h5", "van", 0)
    m = tmp_path / "x" / "fielddiag-manifest.csv"
    m.write_text("before,after,added_mass_kg\none.h5,two.h5,55.5\n")
    sessions, manifests = find_sessions([tmp_path])
    assert manifests == [m.resolve()] and len(sessions) == 3
    from fielddiag.batch.discover import read_headers

    pairing = pair_sessions(read_headers(sessions), manifests)
    assert [(p.before.name, p.after.name, p.added_mass_kg) for p in pairing.pairs] == [
        ("one.h5", "two.h5", 55.5)]
    assert [p.name for p, _ in pairing.unpaired] == [c.name]
    assert a.exists() and b.exists()
    for text, needle in [("before;after\n", "columns before,after"),
                         ("before,after,added_mass_kg\none.h5,,5\n", "line 2"),
                         ("before,after,added_mass_kg\none.h5,two.h5,-5\n", "kg -5: give")]:
        m.write_text(text)
        with pytest.raises(FieldDiagError, match=needle):
            read_manifest(m)
    m.write_text("before,after\none.h5,missing.h5\n")
    with pytest.raises(FieldDiagError, match="missing.h5, which does not exist"):
        pair_sessions(read_headers(sessions), [m])


def test_bad_input_is_one_clear_line(tmp_path, capsys):
    assert main(["reprocess", str(tmp_path / "nowhere")]) == 1
    assert "does not exist" in capsys.readouterr().err
    assert main(["reprocess", str(tmp_path / "*.h5")]) == 1
    assert "matches no file" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["reprocess", str(tmp_path / "empty")]) == 1
    assert "no session files" in capsys.readouterr().err
    assert main(["reprocess", str(tmp_path), "--workers", "0"]) == 1
    assert "--workers 0: give worker processes, a whole number from 1" in capsys.readouterr().err
    _tiny_session(tmp_path / "s.h5", "v", 0)
    assert main(["reprocess", str(tmp_path), "--steps", "identify,fly"]) == 1
    assert "unknown step 'fly'" in capsys.readouterr().err


def test_unreachable_scheduler_is_a_clear_error(tmp_path, capsys):
    _tiny_session(tmp_path / "b.h5", "v", 0)
    _tiny_session(tmp_path / "a.h5", "v", 50)
    t0 = time.monotonic()
    assert main(["reprocess", str(tmp_path), "--scheduler", "tcp://127.0.0.1:9"]) == 1
    err = capsys.readouterr().err
    assert "cannot reach the dask scheduler at tcp://127.0.0.1:9" in err
    assert "Traceback" not in err
    assert time.monotonic() - t0 < 60


# ------------------------------------------------------------------ a real local cluster
def _write_pair(folder: Path, vehicle: str, seed: int, mass_kg: float = 60.0) -> tuple[Path, Path]:
    before, after = simulate_pair(CAR, added_mass_kg=mass_kg, seed=seed, duration_s=40.0)
    folder.mkdir(parents=True, exist_ok=True)
    return (drive_to_session(before, folder / "before.h5", vehicle=vehicle),
            drive_to_session(after, folder / "after.h5", vehicle=vehicle))


def _corrupt_body_samples(path: Path) -> None:
    """Overwrite the body channel's stored chunks with 0xFF bytes (NaN): the header still
    reads, the samples are garbage, as after a bad sector or a half-copied file."""
    import h5py

    with h5py.File(path, "r") as f:
        ds = f["daq/channels/body_z"]
        chunks = [ds.id.get_chunk_info(i) for i in range(ds.id.get_num_chunks())]
    with open(path, "r+b") as fh:
        for c in chunks:
            fh.seek(c.byte_offset)
            fh.write(b"\xff" * c.size)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    _write_pair(root / "car-a", "car-a", seed=11)
    _write_pair(root / "car-b", "car-b", seed=12)
    _, bad_after = _write_pair(root / "car-c", "car-c", seed=13)
    _corrupt_body_samples(bad_after)
    _, truncated = _write_pair(root / "car-d", "car-d", seed=14)
    data = truncated.read_bytes()
    truncated.write_bytes(data[: len(data) // 3])  # header unreadable
    (root / "car-e").mkdir()
    _tiny_session(root / "car-e" / "lonely.h5", "car-e", 0.0)
    return root


@pytest.fixture(scope="module")
def first_run(fleet):
    """The batch run once over the fleet on a LocalCluster with 2 workers (all steps)."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    out, err = io.StringIO(), io.StringIO()
    t0 = time.monotonic()
    with redirect_stdout(out), redirect_stderr(err):
        rc = main(["reprocess", str(fleet), "--workers", "2"])
    return rc, out.getvalue(), err.getvalue(), time.monotonic() - t0


def test_reprocess_on_local_cluster_with_2_workers(fleet, first_run):
    rc, out, err, _ = first_run
    assert rc == 1, out + err  # some pairs failed: the batch says so
    assert "local cluster" in err and "with 2 workers" in err
    db = BatchCatalog(fleet / CATALOG_NAME)
    rows = {r["before"].split("/")[0]: r for r in db.rows()}
    assert set(rows) == {"car-a", "car-b", "car-c"}
    for car in ("car-a", "car-b"):
        r = rows[car]
        assert r["status"] == "done" and r["message"] == ""
        m = r["identify_summary"]["sprung_mass_kg"]
        k = r["identify_summary"]["stiffness_n_per_m"]
        assert abs(m - CAR.body_mass_kg) / CAR.body_mass_kg < 0.05
        assert abs(k - CAR.suspension_stiffness_n_per_m) / CAR.suspension_stiffness_n_per_m < 0.05
        assert r["diagnose_summary"]["verdict"] == "adequate"  # a linear car
        stored = json.loads((fleet / car / "before.identify.json").read_text())
        assert stored["provenance"]["fingerprint"] == r["identify_fingerprint"]
        assert stored["sprung_mass_kg"]["value"] == pytest.approx(m)
        diag = json.loads((fleet / car / "before.diagnose.json").read_text())
        assert diag["verdict"] == "adequate"
    # both worker processes took part
    assert len({rows[c]["worker"] for c in ("car-a", "car-b", "car-c")}) >= 2
    # the corrupt session fails alone, with the reason, and no result file is left
    bad = rows["car-c"]
    assert bad["status"] == "failed" and "NaN or inf" in bad["message"]
    assert not list((fleet / "car-c").glob("*.json"))
    # the final table: every pair, the unreadable session and the unpaired one
    assert "NaN or inf" in out
    assert "car-d/after.h5: cannot read the session header" in out
    assert "car-e/lonely.h5: no drive with added mass" in out
    assert "2 processed, 0 up to date, 2 failed" in out
    # no temporary files left behind
    assert not [p for p in fleet.rglob(".*.tmp")]


def test_dashboard_session_list_reads_the_catalog(fleet, first_run):
    summaries = {s.path: s for s in Catalog(fleet).scan()}
    a_before, a_after = summaries["car-a/before.h5"], summaries["car-a/after.h5"]
    assert a_before.batch["role"] == "before" and a_before.batch["partner"] == "car-a/after.h5"
    assert a_after.batch["status"] == "done" and "adequate" in a_after.batch["result"]
    assert a_after.processed["identify"] == "car-a/before.identify.json"
    assert summaries["car-c/after.h5"].batch["status"] == "failed"
    assert summaries["car-d/after.h5"].error  # unreadable, still listed


def test_rerun_skips_finished_work_and_retries_failures(fleet, first_run):
    done_json = fleet / "car-a" / "before.identify.json"
    mtime = done_json.stat().st_mtime_ns
    batch = plan([fleet])
    assert [Path(j.after).parent.name for j in batch.jobs] == ["car-c"]  # only the failed one
    assert {Path(o.after).parent.name for o in batch.up_to_date} == {"car-a", "car-b"}
    assert len(plan([fleet], force=True).jobs) == 3
    # a session changed since: its pair is stale again
    os.utime(fleet / "car-b" / "after.h5")
    assert {Path(j.after).parent.name for j in plan([fleet]).jobs} == {"car-b", "car-c"}
    os.utime(fleet / "car-b" / "after.h5", ns=(mtime, mtime))
    # a lost catalog is rebuilt from the fingerprints in the result files
    (fleet / CATALOG_NAME).rename(fleet / "lost.sqlite")
    try:
        stale = plan([fleet])
        assert "car-a" not in {Path(j.after).parent.name for j in stale.jobs}
    finally:
        (fleet / "lost.sqlite").replace(fleet / CATALOG_NAME)
    assert done_json.stat().st_mtime_ns == mtime


# --------------------------------------------------------------------- a killed worker
def _die_on_car_x(job: PairJob) -> PairOutcome:
    if "car-x" in job.before:
        os._exit(9)  # as if the OOM killer or a segfault took the worker
    time.sleep(0.2)
    return PairOutcome(job.before, job.after, job.added_mass_kg, job.vehicle, job.corner,
                       [StepOutcome("identify", "done")])


def test_a_killed_worker_fails_its_pair_only():
    import cloudpickle

    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    jobs = [PairJob(f"/fleet/{c}/before.h5", f"/fleet/{c}/after.h5", 50.0, ("identify",),
                    {"identify": ""}, {"identify": c}) for c in ("car-w", "car-x", "car-y")]
    outcomes = {Path(o.before).parent.name: o for o in run_jobs(jobs, workers=2,
                                                                task=_die_on_car_x)}
    assert outcomes["car-w"].status == "done" and outcomes["car-y"].status == "done"
    assert outcomes["car-x"].status == "failed"
    assert "worker processing this pair died" in outcomes["car-x"].message


def test_catalog_is_plain_sqlite(fleet, first_run):
    with sqlite3.connect(fleet / CATALOG_NAME) as db:
        n, failed = db.execute(
            "SELECT count(*), sum(status = 'failed') FROM pairs").fetchone()
    assert (n, failed) == (3, 1)


def test_runs_on_an_existing_cluster_given_its_address(fleet, first_run, tmp_path, capsys):
    """A real `dask scheduler` and `dask worker` in their own processes, as on a fleet's
    machines; the batch connects to the scheduler's address."""
    import shutil
    import subprocess

    shutil.copytree(fleet / "car-a", tmp_path / "car-a", ignore=shutil.ignore_patterns("*.json"))
    sched_file = tmp_path / "scheduler.json"
    env = {**os.environ, "DASK_DISTRIBUTED__LOGGING__DISTRIBUTED": "error"}
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler",
                               "--host", "127.0.0.1", "--port", "0", "--dashboard-address",
                               ":0", "--scheduler-file", str(sched_file)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        for _ in range(200):
            if sched_file.exists() and sched_file.stat().st_size:
                break
            time.sleep(0.1)
        address = json.loads(sched_file.read_text())["address"]
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker",
                                       address, "--nthreads", "1", "--no-dashboard"], env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client

        with Client(address, timeout="30s") as c:
            c.wait_for_workers(1, timeout=60)
        rc = main(["reprocess", str(tmp_path), "--scheduler", address, "--steps", "identify"])
        out, err = capsys.readouterr()
        assert rc == 0, out + err
        assert f"running on a cluster at {address} with 1 workers" in err
        row = BatchCatalog(tmp_path / CATALOG_NAME).rows()[0]
        assert row["status"] == "done" and row["diagnose_status"] is None
        assert abs(row["identify_summary"]["sprung_mass_kg"] / CAR.body_mass_kg - 1) < 0.05
        assert (tmp_path / "car-a" / "before.identify.json").is_file()
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_dry_run_lists_the_plan_and_writes_nothing(tmp_path, capsys):
    _tiny_session(tmp_path / "b.h5", "v", 0)
    _tiny_session(tmp_path / "a.h5", "v", 50)
    assert main(["reprocess", str(tmp_path), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "would run identify+diagnose: b.h5 + a.h5 (+50 kg)" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5", "b.h5"]
