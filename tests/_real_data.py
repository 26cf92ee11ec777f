"""Where the real third-party data (shared/data, see its README.md) is on this machine."""

from __future__ import annotations

from pathlib import Path


def shared_data() -> Path:
    """``shared/data`` beside the checkout (CI, /work/main), else /work/shared/data (a
    worktree under /work/wt); tests that need a file skip when it is in neither."""
    beside = Path(__file__).resolve().parents[2] / "shared" / "data"
    return beside if beside.is_dir() else Path("/work/shared/data")


DATA = shared_data()
CAN_LOG = DATA / "can" / "comma2k19_rav4_2018-08-02_seg40.log"
PT_DBC = DATA / "can" / "toyota_new_mc_pt_generated.dbc"
ADAS_DBC = DATA / "can" / "toyota_adas.dbc"
MR_DAMPER = DATA / "mr_damper"
