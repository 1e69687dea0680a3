"""The drives as the machine the loop steps (no rclpy): ``CanopenHardware`` gives
pkm_sim_hw.sim_loop.SimLoop what a simulated plant gives it (``step``, ``output``,
``safe_stop``, the step count and the stop), over a CanopenMaster. So the drive
interface is sim_hw's loop on other hardware: the same lockstep and real-time
exchange, command authority, watchdog, E-stop and summary, and the controller sees
the same ``drives/state`` (ros2_control's hardware interface boundary, one loop on
either side of it).

One ``step`` is one bus cycle (canopen_master: RPDOs, SYNC, TPDOs); a drive's trip
found in it (canopen_master.CanopenMaster.check) stops the machine with its cause:
quick stop on every drive at once, then in every cycle. A real machine has no ground
truth: its output has no tool pose (``tool_pose`` None), and it takes no simulated
load.
"""

from __future__ import annotations

from dataclasses import dataclass

from pkm_common.causes import TripCause
from pkm_kinematics.errors import FieldError
from pkm_sim_hw.plant import PlantOutput

from .canopen_master import CanopenMaster, DriveTrip, Reading
from .cia402 import State
from .drive_config import DriveSettings
from .virtual_drive import Sample

__all__ = ["CanopenHardware", "HardwareParameters", "PlantAxes"]


@dataclass(frozen=True)
class HardwareParameters:
    dt_s: float


class CanopenHardware:
    """The machine of ``settings``'s drives through ``master`` at period ``dt_s``."""

    def __init__(self, master: CanopenMaster, settings: DriveSettings, dt_s: float):
        self.master, self.settings = master, settings
        self.n, self.names = settings.n, list(settings.names)
        self.params = HardwareParameters(dt_s)
        self.dt_ns = round(dt_s * 1e9)
        self.k, self.t = 0, 0.0
        self.stopped, self.stop_reason, self.stop_cause = False, "", TripCause.NONE
        self.trips: list[DriveTrip] = []             # what the supervision found at the stop
        self.not_stopped: list[str] = []              # drives that did not confirm the quick stop
        self.reading: Reading | None = None
        self.homing: list[Reading] = []               # the homing cycles' readings
        self._last: PlantOutput | None = None

    def start(self) -> None:
        """Boot the drives, home them (the machine file's homing, if any: their
        readings kept in ``homing``), and switch them on, brakes closed (DriveStartError
        naming a drive that cannot); step 0 is the first SYNC with every drive switched
        on. The first step enables them with its forces (CanopenMaster.release)."""
        self.master.boot()
        self.homing = self.master.home()
        self.reading = self.master.enable(State.SWITCHED_ON)
        self.master.release()
        self._last = self._output(self.reading)

    @property
    def homed(self) -> bool:
        return self.master.homed

    def step(self, forces, hold: bool = False) -> PlantOutput:
        """One bus cycle on ``forces`` (N or N m, one per drive)."""
        if len(forces) != self.n:
            raise FieldError("drive forces", f"expected {self.n} values, got {len(forces)}")
        self.reading = self.master.cycle(forces)
        self.k += 1
        self.t = self.k * self.params.dt_s
        if not self.stopped:
            trips = self.master.check(self.reading)
            if trips:
                self.trips = trips
                self.safe_stop(trips[0].text(), trips[0].cause)
        self._last = self._output(self.reading)
        return self._last

    def safe_stop(self, reason: str, cause: TripCause = TripCause.PLANT_SAFE_STOP) -> None:
        """Quick stop on every drive (the first stop's reason and cause are kept)."""
        if self.stopped:
            return
        self.stopped, self.stop_reason, self.stop_cause = True, reason, TripCause(cause)
        self.not_stopped = self.master.quick_stop()

    def output(self) -> PlantOutput:
        return self._last

    def drive_states(self) -> list[tuple[State | None, int]]:
        """Each drive's CiA 402 state and statusword of the last cycle."""
        r = self.reading
        return list(zip(r.states, r.statuswords)) if r else []

    def load_components(self, force, moment):
        raise FieldError("load", "the drives of a real machine take no simulated load")

    def _output(self, r: Reading) -> PlantOutput:
        faults = [f"{k}:{st.label if st else 'unknown'}" for k, st in enumerate(r.states)
                  if st is not State.OPERATION_ENABLED and (self.k or st is not State.SWITCHED_ON)]
        return PlantOutput(self.t, self.k, self.k * self.dt_ns, list(r.positions), list(r.velocities),
                           list(r.forces), list(r.limited), None, None, [], 0.0, faults, self.stopped)


class PlantAxes:
    """A simulated plant (pkm_sim_hw.plant.Plant or StrutPlant) as the physics of
    virtual drives (virtual_drive.Axes): its encoders are what they report, its
    applied forces their torque actual; a drive whose brake holds holds the platform
    (the plant's ``hold``: a parallel machine does not move with one drive braked,
    and the drive interface quick-stops every drive at once anyway)."""

    def __init__(self, plant):
        self.plant, self.n = plant, plant.n
        plant.pause_schedules()                        # its loads come with the run (restart)

    def samples(self, out: PlantOutput | None = None):
        out = out or self.plant.output()
        offsets = self.plant.encoders.offsets or [0.0] * self.n
        return [Sample(p, v, f, p - o) for p, v, f, o in zip(out.encoder_positions, out.encoder_velocities,
                                                             out.applied_forces, offsets)]

    def restart(self) -> None:
        self.plant.restart_clock()

    def step(self, forces):
        hold = any(f is None for f in forces)
        return self.samples(self.plant.step([0.0 if f is None else f for f in forces], hold=hold))
