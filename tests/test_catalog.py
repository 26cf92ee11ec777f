"""The catalog of sessions under a root: summaries, results beside sessions, safe paths."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

import fielddiag.catalog as catalog_mod
from fielddiag.catalog import (
    Catalog,
    OutsideRootError,
    filter_sessions,
    relative_to_root,
    resolve_under_root,
    result_path,
    sort_sessions,
)
from fielddiag.channels import ChannelSpec, Event, Gap, SessionMetadata, SignalSpec
from fielddiag.errors import SessionError
from fielddiag.session import write_session

FS_HZ = 200.0


def _session(path: Path, *, vehicle: str, corner: str, mass_kg: float, n: int) -> Path:
    t = np.arange(n) / FS_HZ
    samples = np.column_stack([np.sin(t), np.cos(t)])
    speed = SignalSpec("vehicle_speed", unit="m/s", source="sim", role="speed")
    return write_session(
        path,
        SessionMetadata(vehicle=vehicle, corner=corner, added_mass_kg=mass_kg, operator="ann"),
        [ChannelSpec("wheel_z", role="wheel"), ChannelSpec("body_z", role="body")],
        samples,
        sample_rate_hz=FS_HZ,
        signals={speed: (t[::10], np.full(t[::10].shape, 12.0))},
        events=[Event(1.0, "bump"), Event(2.0, "pothole")],
        gaps=[Gap(3.0, 3.1, 20, "usb")],
    )


@pytest.fixture
def root(tmp_path: Path) -> Path:
    r = tmp_path / "root"
    (r / "car-a").mkdir(parents=True)
    (r / "car-b" / "deep").mkdir(parents=True)
    _session(r / "car-a" / "before.h5", vehicle="Golf", corner="front-left", mass_kg=0, n=2000)
    _session(r / "car-a" / "after.h5", vehicle="Golf", corner="front-left", mass_kg=60, n=3000)
    _session(r / "car-b" / "deep" / "drive.h5", vehicle="Astra", corner="rear-right",
             mass_kg=0, n=1000)
    return r


def test_scan_summarises_every_session_from_its_header(root: Path) -> None:
    cat = Catalog(root)
    found = {s.path: s for s in cat.scan()}
    assert sorted(found) == ["car-a/after.h5", "car-a/before.h5", "car-b/deep/drive.h5"]
    after = found["car-a/after.h5"]
    assert after.vehicle == "Golf" and after.corner == "front-left"
    assert after.added_mass_kg == 60.0
    assert after.duration_s == pytest.approx(3000 / FS_HZ)
    assert after.sample_rate_hz == FS_HZ
    assert after.channels == ("wheel_z", "body_z")
    assert after.signals == ("vehicle_speed",)
    assert (after.n_events, after.n_gaps, after.samples_lost) == (2, 1, 20)
    assert after.closed_cleanly and after.error == ""
    assert after.created.endswith("Z")
    assert json.loads(json.dumps(after.to_dict()))["channels"] == ["wheel_z", "body_z"]


def test_results_beside_a_session_mark_it_processed(root: Path) -> None:
    cat = Catalog(root)
    assert all(s.processed == {} for s in cat.scan())
    before = root / "car-a" / "before.h5"
    result_path(before, "identify").write_text("{}")
    (root / "car-a" / "before.h5.diagnose.json").write_text("{}")
    (root / "car-a" / "unrelated.json").write_text("{}")
    found = {s.path: s for s in cat.scan()}
    assert found["car-a/before.h5"].processed == {
        "diagnose": "car-a/before.h5.diagnose.json",
        "identify": "car-a/before.identify.json",
    }
    assert found["car-a/after.h5"].processed == {}
    assert cat.summary("car-a/before.h5").processed["identify"] == "car-a/before.identify.json"


def test_rescan_reads_a_header_only_when_the_file_changed(
    root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[str] = []
    real = catalog_mod._read_header

    def counting(path, rel, st):
        calls.append(rel)
        return real(path, rel, st)

    monkeypatch.setattr(catalog_mod, "_read_header", counting)
    cat = Catalog(root)
    cat.scan()
    assert len(calls) == 3
    cat.scan()
    assert len(calls) == 3  # all cached
    target = root / "car-b" / "deep" / "drive.h5"
    target.unlink()
    _session(target, vehicle="Corsa", corner="rear-right", mass_kg=0, n=1500)
    os.utime(target, ns=(1, 2_000_000_000_000_000_000))  # make sure the mtime differs
    found = {s.path: s for s in cat.scan()}
    assert calls[3:] == ["car-b/deep/drive.h5"]
    assert found["car-b/deep/drive.h5"].vehicle == "Corsa"


def test_broken_and_hidden_files(root: Path) -> None:
    (root / "car-a" / "broken.h5").write_bytes(b"not an hdf5 file at all")
    (root / "car-a" / ".before.h5.partial-123").write_bytes(b"partial")
    (root / ".hidden").mkdir()
    _session(root / ".hidden" / "x.h5", vehicle="x", corner="x", mass_kg=0, n=100)
    found = {s.path: s for s in Catalog(root).scan()}
    assert "car-a/broken.h5" in found and found["car-a/broken.h5"].error
    assert not any(".hidden" in p or "partial" in p for p in found)


def test_symlinked_session_outside_root_is_not_listed(root: Path, tmp_path: Path) -> None:
    outside = _session(tmp_path / "secret.h5", vehicle="secret", corner="x", mass_kg=0, n=100)
    (root / "car-a" / "link.h5").symlink_to(outside)
    paths = [s.path for s in Catalog(root).scan()]
    assert "car-a/link.h5" not in paths and len(paths) == 3


@pytest.mark.parametrize(
    "bad",
    ["../secret.h5", "car-a/../../secret.h5", "/etc/passwd", "C:\\Windows\\win.ini", "",
     "a\0b", "..", "car-a/../.."],
)
def test_resolve_under_root_refuses_paths_outside(root: Path, bad: str) -> None:
    with pytest.raises(OutsideRootError):
        resolve_under_root(root, bad)


def test_resolve_under_root_refuses_symlinks_out_and_accepts_inside(
    root: Path, tmp_path: Path
) -> None:
    (tmp_path / "outside").mkdir()
    (root / "escape").symlink_to(tmp_path / "outside")
    with pytest.raises(OutsideRootError):
        resolve_under_root(root, "escape/anything.h5")
    inside = resolve_under_root(root, "car-a/../car-a/before.h5")
    assert inside == (root / "car-a" / "before.h5").resolve()
    assert relative_to_root(root, inside) == "car-a/before.h5"
    with pytest.raises(OutsideRootError):
        relative_to_root(root, tmp_path / "outside")
    assert issubclass(OutsideRootError, SessionError)


def test_filter_and_sort(root: Path) -> None:
    sessions = Catalog(root).scan()
    assert [s.path for s in filter_sessions(sessions, "golf")] == [
        "car-a/after.h5", "car-a/before.h5"]
    assert [s.path for s in filter_sessions(sessions, "REAR astra")] == ["car-b/deep/drive.h5"]
    assert filter_sessions(sessions, "golf astra") == []
    assert len(filter_sessions(sessions, "  ")) == 3
    by_duration = sort_sessions(sessions, "duration_s", descending=True)
    assert [s.duration_s for s in by_duration] == [15.0, 10.0, 5.0]
    with pytest.raises(SessionError):
        sort_sessions(sessions, "no_such_field")


def test_missing_root_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="does not exist"):
        Catalog(tmp_path / "nope")
    with pytest.raises(SessionError, match="no session"):
        Catalog(tmp_path).summary("missing.h5")
