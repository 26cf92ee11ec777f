"""A simulated drive recorded through the virtual devices: one harness for the CLI and the UI.

:class:`VirtualDrive` runs the virtual devices behind a recording and the
:class:`fielddiag.recorder.Recorder` that reads them, and starts and stops them together:

* the virtual DAQ (:class:`drivers.virtual.VirtualDAQ`) streams a simulated drive
  (:func:`drivers.virtual.simulated_accelerations`: channel 0 wheel, 1 body, the others
  noise) in real time on a pseudo-terminal, read back through the real serial driver;
  faults (corrupted bytes, garbage, a stall, a pulled cable) are injected by the device;
* the virtual ECU (:class:`drivers.virtual.VirtualECU`) publishes the drive's speed and
  wheel speeds on an in-process python-can ``virtual`` bus, read by the real CAN driver
  (signals ``vehicle_speed`` (role speed) and ``WHEEL_SPEED_FL/FR/RL/RR``, in m/s). It
  plays the drive in step with the virtual DAQ (:meth:`drivers.virtual.VirtualDAQ.
  data_time_s`): what it sends at the time DAQ sample k is acquired is the drive at
  sample k;
* in full-vehicle mode (``full_vehicle=True``, or a full-vehicle ``drive``) the drive is
  :func:`fielddiag.vehicle.simulate_vehicle`'s: eight DAQ channels given their corner
  roles by the serial driver's channel map, and the ECU also sends the car's
  longitudinal and lateral accelerations (:mod:`fielddiag.virtual_streams`); the session
  is a full-vehicle session (:func:`fielddiag.vehicle.read_vehicle_recording`);
* other sources (a real serial DAQ, a real CAN bus) may be recorded alongside.

The drive is streamed once (``fielddiag demo``: :func:`record_virtual_drive`) or in a loop
(the dashboard's live page: :class:`fielddiag.web.live_control.LiveRecording`). Stopping
stops the recorder first, so that everything the devices sent and the host received is
stored, then the devices.
"""

from __future__ import annotations

import os
import threading
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from drivers.base import Source
from fielddiag.channels import SessionMetadata
from fielddiag.errors import DeviceError, FieldDiagError
from fielddiag.virtual_streams import (
    ECU_SIGNALS,
    DriveStream,
    full_vehicle_stream,
    is_vehicle_drive,
    quarter_car_stream,
)

__all__ = ["ECU_SIGNALS", "LOOP_DRIVE_S", "VirtualDrive", "record_virtual_drive"]

#: Length of the drive streamed in a loop when a recording has no set length [s].
LOOP_DRIVE_S = 120.0
#: Longest wait for the on-line estimator (compiled before the start) to be attached.
_ONLINE_ATTACH_S = 10.0


class VirtualDrive:
    """The virtual devices of a simulated drive and the recorder reading them.

    Parameters
    ----------
    path : str or Path
        Session file to create.
    drive_s : float
        Length of the simulated drive [s]; with ``loop`` the devices start it again at
        its end, otherwise the DAQ stops sending and the ECU one second later.
    virtual_daq : bool
        Stream the drive through a virtual DAQ on a pseudo-terminal.
    virtual_ecu : bool
        Publish the drive's speeds through a virtual ECU on a python-can virtual bus.
    sources : sequence of drivers.base.Source
        Other sources to record alongside (configured, not opened), e.g. a real CAN bus
        beside the virtual DAQ. With ``virtual_daq`` they must not include a DAQ.
    metadata : SessionMetadata or None
        Vehicle, corner, operator, notes and the added mass [kg], which is also the mass
        put on the simulated body. ``extra["virtual_drive"]`` (seed, rate [Hz], drive
        length [s], loop) and, with ``include_recipe``, ``extra["simulation"]`` are added;
        a full-vehicle drive adds the vehicle file and where the added mass sits.
    sample_rate_hz : float
        Rate of the virtual DAQ [Hz].
    n_channels : int
        Channels of the virtual DAQ (at least 2: wheel, body, then noise).
    seed : int
        Seeds the simulated road, speed profile, noise and the devices' faults.
    params, effects, road_class : optional
        Passed to the simulator (default car, no effects, ISO 8608 class C road). Full
        vehicle: a ``VehicleParams`` and a mapping corner -> effects.
    drive : fielddiag.sim.SimulatedDrive, fielddiag.vehicle.VehicleDrive or None
        Stream this drive instead of simulating one (its rate and added mass are used; a
        full-vehicle drive sets full-vehicle mode).
    full_vehicle : bool
        Simulate and stream a full vehicle (eight channels, see the module docstring).
    added_mass_at_m : (x_m, y_m) or None
        Full vehicle: where the added mass sits (required with an added mass).
    manoeuvre : str
        Full vehicle: ``rough_road``, ``ramp_steer`` or ``braking``.
    loop : bool
        Stream the drive again and again (a recording as long as the user wants).
    faults : mapping or None
        Fault keywords of :class:`drivers.virtual.VirtualDAQ` (``corrupt_rate``,
        ``garbage_every_s``, ``stall_at_s``, ``stall_for_s``, ``tx_buffer_bytes``,
        ``disconnect_at_s``, ``disconnect_for_s``...); only with ``virtual_daq``.
    online : bool or mapping
        Estimate stiffness and damping on-line while recording
        (:meth:`fielddiag.recorder.Recorder.attach_online_estimator`; a mapping gives its
        keyword arguments, ``added_mass_kg`` defaulting to the metadata's). The
        estimator is compiled before the devices start, so it sees the whole drive.
    include_recipe : bool
        Store how the drive was simulated in ``extra["simulation"]``.
    overwrite : bool
        Replace an existing session file.

    Raises
    ------
    DeviceError
        Nothing to record, or faults without a virtual DAQ.

    Examples
    --------
    >>> run = VirtualDrive("drive.h5", drive_s=32.0).start()
    >>> final = run.record_for(30.0, progress=print)   # the final status; run.error if it failed
    """

    def __init__(
        self,
        path: str | os.PathLike,
        *,
        drive_s: float,
        virtual_daq: bool = True,
        virtual_ecu: bool = True,
        sources: Sequence[Source] = (),
        metadata: SessionMetadata | None = None,
        sample_rate_hz: float = 500.0,
        n_channels: int = 2,
        seed: int = 0,
        params: Any = None,
        effects: Sequence[Any] = (),
        road_class: str | None = "C",
        drive: Any = None,
        full_vehicle: bool = False,
        added_mass_at_m: tuple[float, float] | None = None,
        manoeuvre: str = "rough_road",
        loop: bool = False,
        faults: Mapping[str, Any] | None = None,
        online: bool | Mapping[str, Any] = False,
        include_recipe: bool = True,
        overwrite: bool = False,
    ) -> None:
        if not (virtual_daq or virtual_ecu or sources):
            raise DeviceError("choose a DAQ and/or a CAN source to record")
        if faults and not virtual_daq:
            raise DeviceError("faults are injected by the virtual DAQ: record it to use them")
        self.path = Path(path)
        self.drive_s = float(drive_s)
        self.virtual_daq = bool(virtual_daq)
        self.virtual_ecu = bool(virtual_ecu)
        self.other_sources = list(sources)
        self.metadata = metadata or SessionMetadata()
        self.sample_rate_hz = float(sample_rate_hz)
        self.n_channels = max(2, int(n_channels))
        self.seed = int(seed)
        self.full_vehicle = bool(full_vehicle) or is_vehicle_drive(drive)
        self.sim_options: dict[str, Any] = {"params": params, "road_class": road_class}
        if self.full_vehicle:
            self.sim_options.update(effects=dict(effects or {}), manoeuvre=manoeuvre,
                                    added_mass_at_m=added_mass_at_m)
        else:
            self.sim_options["effects"] = tuple(effects)
        self.drive = drive
        self.loop = bool(loop)
        self.faults = dict(faults or {})
        self.online = online
        self.include_recipe = include_recipe
        self.overwrite = overwrite
        self.recorder: Any = None  # fielddiag.recorder.Recorder once started
        self.final_status: dict[str, Any] | None = None
        self.error: FieldDiagError | None = None
        self.online_error = ""
        #: The virtual DAQ and ECU once started (kept after :meth:`stop`: their counts
        #: are the ground truth of what was sent).
        self.daq_device: Any = None
        self.ecu_device: Any = None
        self._bus: Any = None  # the ECU's python-can bus
        self._devices_stopped = False
        self._stop_lock = threading.Lock()
        if drive is not None:
            self.sample_rate_hz = float(drive.sample_rate_hz)
            self.metadata = replace(self.metadata, added_mass_kg=float(drive.added_mass_kg))

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> VirtualDrive:
        """Start the devices, open the sources and start recording.

        Returns
        -------
        VirtualDrive
            self, recording.

        Raises
        ------
        FieldDiagError
            A source cannot be opened, the disk is full...; everything started is
            stopped again first.
        """
        from fielddiag.recorder import Recorder

        online_kw = self._online_kwargs()
        if online_kw is not None:
            online_kw = self._warm_up(online_kw)
        try:
            stream, sources = self._start_devices()
            self.recorder = Recorder(self.path, sources, metadata=self._metadata(stream),
                                     overwrite=self.overwrite)
            self.recorder.start()
            if online_kw is not None:
                self._attach_online(online_kw)
            if self.ecu_device is not None:
                self.ecu_device.time_fn = self._ecu_clock()
                self.ecu_device.start()
        except BaseException:
            self._stop_quietly()
            raise
        return self

    def _online_kwargs(self) -> dict[str, Any] | None:
        if not self.online:
            return None
        kw = dict(self.online) if isinstance(self.online, Mapping) else {}
        kw.setdefault("added_mass_kg", self.metadata.added_mass_kg)
        return kw

    def _warm_up(self, online_kw: dict[str, Any]) -> dict[str, Any] | None:
        """Compile the estimator now, not during the drive (it then sees all of it).

        An estimator that cannot be made leaves the recording alone: None, and
        :attr:`online_error` says why.
        """
        if not (self.virtual_daq or any(s.kind == "daq" for s in self.other_sources)):
            self.online_error = "no DAQ: nothing to estimate from"
            return None
        if self.full_vehicle:
            self.online_error = ("the on-line estimate is for one corner (a wheel and a body "
                                 "channel), not the full vehicle")
            return None
        try:
            from fielddiag.identify.online import OnlineEstimator

            OnlineEstimator(self.sample_rate_hz, **online_kw).warm_up()
        except TypeError:  # a keyword the estimator does not take: the caller's mistake
            raise
        except Exception as exc:
            self.online_error = f"the on-line estimator cannot run: {exc}"
            return None
        return online_kw

    def _stream(self) -> DriveStream | None:
        """What the virtual devices play (simulated now unless a drive was given)."""
        if not (self.virtual_daq or self.virtual_ecu):
            return None
        common = {"drive_s": self.drive_s, "sample_rate_hz": self.sample_rate_hz,
                  "added_mass_kg": self.metadata.added_mass_kg, "seed": self.seed,
                  "with_daq": self.virtual_daq, "drive": self.drive, **self.sim_options}
        if self.full_vehicle:
            return full_vehicle_stream(**common)
        return quarter_car_stream(n_channels=self.n_channels, **common)

    def _start_devices(self) -> tuple[DriveStream | None, list[Source]]:
        """What is played, and the sources in order: virtual DAQ, others, ECU."""
        from drivers.virtual import VirtualDAQ

        stream = self._stream()
        daq_sources: list[Source] = []
        if self.virtual_daq:
            from drivers.serial_daq import SerialDAQSource

            scale = {} if stream.full_scale_mps2 is None else {
                "full_scale_mps2": stream.full_scale_mps2}
            self.daq_device = VirtualDAQ(
                stream.signals_mps2, sample_rate_hz=self.sample_rate_hz, loop=self.loop,
                seed=self.seed, roles=stream.daq_roles,
                link_name=f"ttyVDAQ{uuid.uuid4().hex[:6]}", **scale, **self.faults)
            self.daq_device.start()
            src = SerialDAQSource.from_url(f"serial://{self.daq_device.path}")
            src.role_map = stream.role_map
            daq_sources.append(src)
        can_sources: list[Source] = []
        if self.virtual_ecu:
            can_sources.append(self._virtual_ecu_source(stream))
        return stream, daq_sources + self.other_sources + can_sources

    def _virtual_ecu_source(self, stream: DriveStream) -> Source:
        import can

        from drivers.can_vehicle import CanBusSource
        from drivers.virtual import VirtualECU

        channel = f"fielddiag-vecu-{uuid.uuid4().hex[:8]}"
        self._bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.ecu_device = VirtualECU(self._bus, stream.speed_time_s, stream.speed_mps,
                                     accel_mps2=stream.accel_mps2, loop=self.loop,
                                     seed=self.seed)
        src = CanBusSource.from_url(f"can://virtual/{channel}")
        src.dbc = self.ecu_device.db
        src.dbc_label = "drivers.virtual.VIRTUAL_ECU_DBC"
        src.add_signals(stream.ecu_signals)
        return src

    def _ecu_clock(self) -> Callable[[], float]:
        """The virtual ECU's clock: the virtual DAQ's data time (the two play one drive in
        step), else the session time."""
        daq = self.daq_device
        if daq is None:
            return self.recorder.clock.now

        def data_time() -> float:
            t = daq.data_time_s()
            return 0.0 if t is None else t

        return data_time

    def _metadata(self, stream: DriveStream | None) -> SessionMetadata:
        extra = dict(self.metadata.extra)
        meta = self.metadata
        if stream is not None:
            drive = stream.drive
            extra.update(stream.extra)
            extra["virtual_drive"] = {"seed": self.seed, "rate_hz": self.sample_rate_hz,
                                      "drive_s": drive.time_s.size / drive.sample_rate_hz,
                                      "loop": self.loop}
            if self.include_recipe:
                extra["simulation"] = stream.recipe
            meta = replace(meta, added_mass_kg=float(drive.added_mass_kg))
        return replace(meta, extra=extra)

    def _attach_online(self, online_kw: dict[str, Any]) -> None:
        rec = self.recorder
        if rec.attach_online_estimator(**online_kw) is None:
            self.online_error = ("the on-line estimate needs a DAQ with a wheel and a body "
                                 "channel")
            return
        rec.online_ready.wait(_ONLINE_ATTACH_S)  # compiled already: attached at once
        self.online_error = rec.online_error

    def stop(self) -> dict[str, Any]:
        """Stop recording, close the session, then stop the devices.

        The recorder stops first: what the devices sent and the host received is stored.
        Safe to call from several threads and more than once (the later calls return the
        same final status). A failure that ended the recording (full disk, device gone)
        is kept in :attr:`error`, not raised.

        Returns
        -------
        dict
            The final :meth:`status` (``state`` ``stopped`` or ``failed``); empty when the
            recording never started.
        """
        with self._stop_lock:
            try:
                if self.recorder is not None and self.final_status is None:
                    try:
                        final = self._with_own_fields(self.recorder.stop())
                    except FieldDiagError as exc:
                        self.error = exc
                        final = self.status()
                    self.final_status = final
            finally:
                self._stop_devices()
            return self.final_status or {}

    def stop_or_raise(self) -> dict[str, Any]:
        """:meth:`stop`, raising the error that ended the recording, if any.

        Returns
        -------
        dict
            The final status.

        Raises
        ------
        FieldDiagError
            What stopped the recording (device gone, disk full...), after everything is
            closed; the session holds all recorded before.
        """
        final = self.stop()
        if self.error is not None:
            raise self.error
        return final

    def _stop_quietly(self) -> None:
        """After a failed start: stop what was started, keep the start's own error."""
        try:
            if self.recorder is not None and self.recorder.running:
                self.recorder.stop()
        except FieldDiagError:
            pass
        finally:
            self.recorder = None  # it never recorded: stop() has nothing to report
            self._stop_devices()

    def _stop_devices(self) -> None:
        if self._devices_stopped:
            return
        self._devices_stopped = True
        for device in (self.ecu_device, self.daq_device):
            if device is not None:
                try:
                    device.stop()
                except Exception:  # stopping must go on: the bus and the pty are next
                    pass
        if self._bus is not None:
            try:
                self._bus.shutdown()
            except Exception:
                pass

    def record_for(
        self,
        duration_s: float,
        *,
        progress: Callable[[dict[str, Any]], None] | None = None,
        progress_interval_s: float = 0.25,
    ) -> dict[str, Any]:
        """Record ``duration_s`` of data (or until the recording ends), then stop.

        With a DAQ, the length is that of the samples stored: a device that starts late
        or falls behind real time on a busy host still gives the drive asked for (the
        recording then takes longer, at most ``max(10 s, duration_s / 2)`` more). Without
        one, it is the session time.

        Parameters
        ----------
        duration_s : float
            Data to record [s].
        progress : callable or None
            Called with :meth:`status` every ``progress_interval_s`` [s] while recording,
            and with the final status once stopped (unless the recording failed).
        progress_interval_s : float
            Seconds between progress calls.

        Returns
        -------
        dict
            The final status (see :meth:`stop`); :attr:`error` says why it failed.

        Raises
        ------
        DeviceError
            Not started.
        """
        rec = self.recorder
        if rec is None:
            raise DeviceError("not recording: start() the virtual drive first")
        next_progress = 0.0
        late_s = max(10.0, 0.5 * duration_s)
        rate_hz = rec.daq.sample_rate_hz if rec.daq is not None else None

        def recorded_s() -> float:
            if rate_hz is None:
                return rec.clock.now()
            return rec.status().get("samples", 0) / rate_hz

        try:
            while (rec.running and recorded_s() < duration_s
                   and rec.clock.now() < duration_s + late_s):
                time.sleep(0.05)
                if progress is not None and time.monotonic() >= next_progress:
                    progress(self.status())
                    next_progress = time.monotonic() + progress_interval_s
        finally:
            final = self.stop()
        if progress is not None and self.error is None:
            progress(final)
        return final

    # ------------------------------------------------------------------ live access
    @property
    def running(self) -> bool:
        """True while recording."""
        return self.recorder is not None and self.recorder.running

    def status(self) -> dict[str, Any]:
        """The recorder's live status, with the error that ended it, if any.

        Returns
        -------
        dict
            :meth:`fielddiag.recorder.Recorder.status` (``{"state": "new"}`` before the
            start); ``last_error`` holds the failure kept by :meth:`stop` and
            ``online_error`` why there is no on-line estimate.
        """
        if self.recorder is None:
            return {"state": "new"}
        return self._with_own_fields(self.recorder.status())

    def _with_own_fields(self, st: dict[str, Any]) -> dict[str, Any]:
        if self.error is not None and not st.get("last_error"):
            st["last_error"] = str(self.error)
        if self.online_error and not st.get("online_error"):
            st["online_error"] = self.online_error
        return st


def record_virtual_drive(
    path: str | os.PathLike,
    *,
    duration_s: float,
    added_mass_kg: float = 0.0,
    seed: int = 0,
    vehicle: str = "virtual car",
    corner: str = "front-left",
    rate_hz: float = 500.0,
    progress: Callable[[dict[str, Any]], None] | None = None,
    n_channels: int = 2,
    params: Any = None,
    effects: Sequence[Any] = (),
    road_class: str | None = "C",
    drive: Any = None,
    full_vehicle: bool = False,
    added_mass_at_m: tuple[float, float] | None = None,
    operator: str = "fielddiag demo",
    notes: str = "",
    include_recipe: bool = True,
    overwrite: bool = False,
    faults: Mapping[str, Any] | None = None,
    online: bool | Mapping[str, Any] = False,
) -> Path:
    """Record a simulated drive through the virtual DAQ (pty) and the virtual ECU.

    The drive is simulated with :func:`fielddiag.sim.simulate` (``added_mass_kg`` on the
    body; :func:`fielddiag.vehicle.simulate_vehicle` for a full vehicle) and streamed
    once, in real time, by a :class:`VirtualDrive`: it takes ``duration_s`` of wall-clock
    time.

    Parameters
    ----------
    path : str or Path
        Session file to create.
    duration_s : float
        Length of the recording [s] (the drive simulated is 2 s longer).
    added_mass_kg : float
        Mass added on the body [kg] (simulation and session metadata).
    seed : int
        Seeds the simulated road, speed profile and noise.
    vehicle, corner, operator, notes : str
        Session metadata.
    rate_hz : float
        DAQ sample rate [Hz].
    progress : callable or None
        Called about 4 times a second with :meth:`fielddiag.recorder.Recorder.status`,
        and with the final status.
    n_channels : int
        DAQ channels (>= 2).
    params, effects, road_class : optional
        Passed to the simulator (default car, no effects, ISO class C road).
    drive : fielddiag.sim.SimulatedDrive, fielddiag.vehicle.VehicleDrive or None
        Stream this drive instead of simulating one (its rate and added mass are used).
    full_vehicle : bool
        Record a full vehicle (eight DAQ channels, the car's accelerations on CAN); set
        by a full-vehicle ``drive``.
    added_mass_at_m : (x_m, y_m) or None
        Full vehicle: where the added mass sits.
    include_recipe : bool
        Store how the drive was made in ``extra["simulation"]``.
    overwrite : bool
        Replace an existing session file.
    faults : mapping or None
        Fault injection passed to :class:`drivers.virtual.VirtualDAQ` (``corrupt_rate``,
        ``garbage_every_s``, ``disconnect_at_s``, ``disconnect_for_s``, ``stall_at_s``...).
    online : bool or mapping
        Estimate stiffness and damping on-line while recording (see
        :class:`VirtualDrive`); its status is under ``"online"`` in what ``progress``
        receives.

    Returns
    -------
    Path
        The session file.

    Raises
    ------
    FieldDiagError
        The recording could not start or stopped early (device gone, disk full); the
        session holds everything recorded before.
    """
    meta = SessionMetadata(vehicle=vehicle, corner=corner, operator=operator,
                           added_mass_kg=float(added_mass_kg), notes=notes)
    run = VirtualDrive(
        path, drive_s=duration_s + 2.0, metadata=meta, sample_rate_hz=rate_hz,
        n_channels=n_channels, seed=seed, params=params, effects=effects,
        road_class=road_class, drive=drive, full_vehicle=full_vehicle,
        added_mass_at_m=added_mass_at_m, faults=faults, online=online,
        include_recipe=include_recipe, overwrite=overwrite,
    ).start()
    run.record_for(duration_s, progress=progress)
    run.stop_or_raise()
    return Path(path)
