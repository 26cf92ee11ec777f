"""The dashboard's forms refuse the numbers the command line refuses, with the same line
(one validation layer: fielddiag.validate), and start nothing."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

pytestmark = pytest.mark.anyio

CSV = "\n".join(["time_s,acc_wheel,acc_body"]
                + [f"{i / 100:.2f},{(i % 7) / 10:.1f},9.81" for i in range(300)]).encode()


def _the(user, marker: str):
    found = user.find(marker=marker).elements
    assert len(found) == 1, f"{len(found)} elements marked {marker!r}"
    return next(iter(found))


@pytest.mark.parametrize("mass", [1e12, -5.0, 2500.0])
async def test_upload_form_refuses_an_impossible_added_mass(dashboard_user, sessions_root: Path,
                                                            mass: float) -> None:
    from nicegui.elements.upload_files import SmallFileUpload

    user = dashboard_user
    await user.open("/")
    await _the(user, "csv-upload").handle_uploads([SmallFileUpload("drive.csv", "text/csv",
                                                                   CSV)])
    await user.should_see("3 columns; check the mapping and press Import")
    _the(user, "csv-added-mass").set_value(mass)
    user.find(marker="csv-import").click()
    await user.should_see("give the mass added to the body for this drive (0 as the car is) "
                          "in kg, a finite number between 0 and 2000")
    assert not (sessions_root / "imports" / "drive.h5").exists()


@pytest.mark.parametrize("mass", [1e12, 0.0, -60.0])
async def test_identify_page_refuses_an_impossible_added_mass(dashboard_user, sessions_root: Path,
                                                              mass: float) -> None:
    from fielddiag.catalog import result_path

    user = dashboard_user
    await user.open("/identify?before=car-a%2Fbefore.h5&after=car-a%2Fafter.h5")
    field = _the(user, "added-mass")
    for _ in range(200):  # the page fills in the sessions' difference first
        if field.value == pytest.approx(60.0):
            break
        await asyncio.sleep(0.05)
    field.set_value(mass)
    user.find(marker="run-identify").click()
    await user.should_see("give the mass added to the body in kg, a finite number between 0 "
                          "and 2000, more than 0")
    assert not result_path(sessions_root / "car-a" / "before.h5", "identify").exists()
