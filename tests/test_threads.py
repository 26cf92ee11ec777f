"""Independent fits on threads (fielddiag.threads)."""

from __future__ import annotations

import threading
import time

import pytest

from fielddiag.threads import THREADS_ENV, default_threads, map_threads, thread_budget


def test_results_come_back_in_the_order_of_the_items_whatever_ran_first():
    ran: list[int] = []

    def slow_first(x: int) -> int:
        time.sleep(0.05 if x == 0 else 0.0)
        ran.append(x)
        return x * x

    assert map_threads(slow_first, [0, 1, 2, 3], workers=2) == [0, 1, 4, 9]
    assert ran[-1] == 0  # 0 slept: the others ran beside it, not after it


def test_the_dearest_items_start_first():
    started: list[str] = []
    lock = threading.Lock()

    def note(x: str) -> str:
        with lock:
            started.append(x)
        time.sleep(0.02)
        return x

    out = map_threads(note, ["cheap", "dear", "middle"], workers=2,
                      cost={"cheap": 1.0, "dear": 9.0, "middle": 5.0}.get)
    assert out == ["cheap", "dear", "middle"]
    assert started[:2] == ["dear", "middle"]


def test_one_worker_runs_on_the_calling_thread_in_order():
    names: list[str] = []
    out = map_threads(lambda x: names.append(threading.current_thread().name) or x,
                      [3, 1, 2], workers=1, cost=float)
    assert out == [3, 1, 2]
    assert set(names) == {threading.current_thread().name}


def test_an_error_in_a_task_reaches_the_caller():
    def boom(x: int) -> int:
        if x == 2:
            raise ValueError("task 2 failed")
        return x

    with pytest.raises(ValueError, match="task 2 failed"):
        map_threads(boom, [1, 2, 3], workers=2)


def test_the_default_reads_the_environment(monkeypatch):
    monkeypatch.setenv(THREADS_ENV, "3")
    assert default_threads() == 3
    monkeypatch.setenv(THREADS_ENV, "lots")
    assert default_threads() >= 1
    monkeypatch.delenv(THREADS_ENV)
    assert default_threads() >= 1


@pytest.mark.parametrize("effect", [
    None,
    ("series_top_mount", {"suspension_damping_ns_per_m": 1800.0, "mount_stiffness_n_per_m": 6e4}),
])
def test_a_fit_on_threads_is_the_fit_on_one(effect):
    """Two sessions simulated on two threads give the fit one thread gives, number for
    number (memoryless, and with an internal state)."""
    from fielddiag.identify.greybox import GreyBoxData, fit_greybox
    from fielddiag.identify.terms import model_from_sim
    from fielddiag.sim import QuarterCarParams, make_effect, simulate_pair

    car = QuarterCarParams()
    eff = [] if effect is None else [make_effect(effect[0], **effect[1])]
    pair = simulate_pair(car, added_mass_kg=60.0, seed=8, duration_s=20.0, effects=eff)
    model, values = model_from_sim(car, eff)
    data = [GreyBoxData.from_drive(d, truth=True) for d in pair]
    start = {k: v * 1.2 for k, v in values.items()} | {"body_mass_kg": 330.0}
    fits = []
    for n in (1, 2):
        with thread_budget(n):
            fits.append(fit_greybox(data, model, initial=dict(start),
                                    mass_bounds_kg=(150.0, 1500.0)))
    one, two = ({p.key: (p.value, p.std) for p in f.parameters} for f in fits)
    assert one == two
    assert fits[0].body_mass_kg == fits[1].body_mass_kg == pytest.approx(380.0, rel=0.02)


def test_a_diagnosis_on_threads_is_the_diagnosis_on_one():
    """The whole diagnosis (screenings, fits, pairs on threads) gives the same JSON."""
    import json

    from fielddiag import sim
    from fielddiag.diagnose.engine import Drive, diagnose_drives

    sensor = sim.SensorModel(output_rate_hz=200.0, snr_db=35.0)
    pair = sim.simulate_pair(
        sim.QuarterCarParams(), added_mass_kg=40.0, seed=5, duration_s=40.0, road_class="C",
        effects=[sim.make_effect("coulomb_friction", friction_force_n=80.0)],
        wheel_sensor=sensor, body_sensor=sensor)
    drives = [Drive(wheel_accel_mps2=d.wheel_accel_mps2, body_accel_mps2=d.body_accel_mps2,
                    sample_rate_hz=d.sample_rate_hz, added_mass_kg=d.added_mass_kg,
                    label=label, name="threads", start_s=0.0)
              for label, d in zip(("before", "after"), pair, strict=True)]
    lines: list[str] = []
    outs = [json.dumps(diagnose_drives(drives, workers=n, progress=lines.append).to_dict(),
                       sort_keys=True, default=str) for n in (1, 2)]
    assert outs[0] == outs[1]
    found = json.loads(outs[1])["findings"]
    assert found and found[0]["effect"] == "coulomb_friction"
    assert sum(line.startswith("fitting ") for line in lines) >= 2 * 6  # every single, twice
