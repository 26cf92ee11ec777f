"""Outputs are refused before the work when their file system is (nearly) full."""

from __future__ import annotations

import shutil

import pytest

from fielddiag.errors import OutputError
from fielddiag.outputs import MIN_FREE_FILE_BYTES, check_folder, check_target


def test_a_target_is_refused_when_less_than_needed_is_free(tmp_path):
    free = shutil.disk_usage(tmp_path).free
    with pytest.raises(OutputError, match=r"r\.json: No space left on device \(\d+ kB free, "
                                          r"at least \d+ MB needed\); free some space"):
        check_target(tmp_path / "r.json", overwrite=True, need_bytes=free + (1 << 30))
    assert list(tmp_path.iterdir()) == []  # the probe left nothing behind
    assert check_target(tmp_path / "r.json", overwrite=True) == tmp_path / "r.json"
    assert free > MIN_FREE_FILE_BYTES


def test_a_plots_folder_on_a_tiny_disk_is_refused(tmp_path):
    import subprocess

    mnt = tmp_path / "tiny"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)],
                      capture_output=True).returncode != 0:
        pytest.skip("mounting a tiny tmpfs needs root")
    try:
        with pytest.raises(OutputError, match="No space left on device"):
            check_folder(mnt / "plots")  # 1 MB free: under the 4 MB plots need
        assert check_target(mnt / "r.json", overwrite=True, need_bytes=1 << 10)
    finally:
        subprocess.run(["umount", str(mnt)], check=False)
