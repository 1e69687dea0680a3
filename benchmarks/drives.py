"""The drive interface's cost and the rates it reaches (pkm_drives), printed as tables:

1. The CiA 402 layer per drive and cycle, without a bus: the statusword decoded, the
   master's next controlword, the drive's state machine on it, SI <-> drive units (the
   pure part of a cycle, what an EtherCAT transport would keep).
2. One bus cycle (RPDOs, SYNC, TPDOs) through ``canopen`` and python-can's virtual bus,
   master and virtual drives in this process, for 1-8 drives on independent masses: its
   CPU time per drive (both sides: the drives' half is not the controller's on a real
   machine) and per cycle.
3. Each machine with a ``drives`` section, its plant behind virtual drives, stepped in
   lockstep as fast as the process goes (the highest rate over the virtual bus), with and
   without the frames' transmission time (bus.TimedBus), against the bus's own limit at
   its bitrate (bus_timing: worst-case stuffing).

    .venv/bin/python benchmarks/drives.py [--cycles 2000]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import time

import can
import canopen

from pkm_drives.bus import TimedBus
from pkm_drives.bus_timing import cycle_load
from pkm_drives.canopen_master import CanopenMaster, pdo_bytes
from pkm_drives.cia402 import DriveStateMachine, MasterSequencer, State, decode_state, statusword
from pkm_drives.drive_config import AxisScaling, drive_settings
from pkm_drives.hardware import CanopenHardware, PlantAxes
from pkm_drives.virtual_drive import DEFAULT_EDS, MassAxes, VirtualMachine
from pkm_kinematics import load_machine
from pkm_sim_hw.parameters import PLANTS
from pkm_sim_hw.plant import Plant, PlantParameters

_channels = itertools.count()


def networks(channel: str, bitrate: int = 0):
    """Two networks on one virtual channel (drives, master); ``bitrate``: the frames
    take their transmission time (pkm_drives.bus.TimedBus), 0: none."""
    nets = []
    for _ in range(2):
        bus = can.Bus(interface="virtual", channel=channel)
        net = canopen.Network(TimedBus(bus, channel, bitrate) if bitrate else bus)
        net.NOTIFIER_CYCLE = 0.05
        nets.append(net.connect())
    return nets


def pure_layer(cycles: int) -> float:
    """us per drive and cycle of the CiA 402 layer alone."""
    drive, master, scaling = DriveStateMachine(), MasterSequencer(), AxisScaling(1e6, 1000.0, 2000.0)
    drive.initialised()
    word = statusword(drive.state)
    start = time.process_time()
    for k in range(cycles):
        state = decode_state(word)
        drive.on_controlword(master.next(state, State.OPERATION_ENABLED))
        word = statusword(drive.state, mode_bits=1 << 12)
        scaling.force_from_drive(scaling.force_to_drive(123.4 + k))
        scaling.position_from_drive(scaling.position_to_drive(0.1 + 1e-6 * k))
    return (time.process_time() - start) / cycles * 1e6


def bench_cycle(n: int, cycles: int) -> tuple[float, float]:
    """(CPU us per cycle, wall us per cycle) of n drives on masses, one process."""
    channel = f"bench_drives_{next(_channels)}"
    machine = load_machine("archi")
    settings = drive_settings(machine, {"interface": "virtual", "channel": channel})
    settings = dataclasses.replace(settings, names=tuple(f"d{k}" for k in range(n)), node_ids=tuple(range(1, n + 1)),
                                   scaling=(settings.scaling[0],) * n, homing_methods=(), homing_order=(),
                                   home_positions=())
    nets = networks(channel)
    try:
        VirtualMachine(nets[0], MassAxes(n, dt_s=0.002), settings.node_ids, settings.scaling).boot()
        master = CanopenMaster(nets[1], settings, DEFAULT_EDS)
        master.boot()
        master.enable()
        forces = [10.0] * n
        for _ in range(50):
            master.cycle(forces)
        cpu, wall = time.process_time(), time.perf_counter()
        for _ in range(cycles):
            master.cycle(forces)
        return (time.process_time() - cpu) / cycles * 1e6, (time.perf_counter() - wall) / cycles * 1e6
    finally:
        for net in nets:
            net.disconnect()


def bench_machine(name: str, dt_s: float, cycles: int, timed: bool) -> tuple[int, float, float]:
    """(drives, steps/s in lockstep over the virtual bus, the bus's own limit in Hz);
    ``timed``: the virtual bus takes the frames' transmission time."""
    config = load_machine(name)
    channel = f"bench_machine_{next(_channels)}"
    settings = dataclasses.replace(drive_settings(config, {"interface": "virtual", "channel": channel}),
                                   homing_methods=(), homing_order=(), home_positions=())     # absolute encoders
    rpdo, tpdo = pdo_bytes(canopen.import_od(str(DEFAULT_EDS), 1))
    limit = cycle_load(settings.bus.bitrate, dt_s, [rpdo] * settings.n, [tpdo] * settings.n,
                       settings.heartbeat_s).max_rate_hz
    nets = networks(channel, settings.bus.bitrate if timed else 0)
    try:
        plant = PLANTS.get(config.kind, Plant)(config, PlantParameters(dt_s=dt_s))
        VirtualMachine(nets[0], PlantAxes(plant), settings.node_ids, settings.scaling).boot()
        hardware = CanopenHardware(CanopenMaster(nets[1], settings, DEFAULT_EDS), settings, dt_s)
        hardware.start()
        hold = [0.0] * settings.n
        start = time.perf_counter()
        for _ in range(cycles):
            hardware.step(hold)
        return settings.n, cycles / (time.perf_counter() - start), limit
    finally:
        for net in nets:
            net.disconnect()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=2000)
    args = parser.parse_args(argv)
    print(f"CiA 402 layer alone (no bus): {pure_layer(max(args.cycles, 1000) * 10):.2f} us CPU per drive and cycle")
    print("\n| drives | CPU per cycle | per drive | wall per cycle |\n|---|---|---|---|")
    rows = [(n, *bench_cycle(n, args.cycles)) for n in (1, 2, 4, 6, 8)]
    for n, cpu, wall in rows:
        print(f"| {n} | {cpu:.0f} us | {cpu / n:.0f} us | {wall:.0f} us |")
    slope = (rows[-1][1] - rows[0][1]) / (rows[-1][0] - rows[0][0])
    print(f"marginal CPU per drive (1 -> 8 drives): {slope:.0f} us per cycle (master and virtual drive together)")
    print("\n| machine | drives | lockstep, untimed virtual bus | timed (TimedBus, 1 Mbit/s) | the bus's limit "
          "(1 Mbit/s) |\n|---|---|---|---|---|")
    for name, dt_s in (("archi", 0.002), ("genhexkins", 0.0025)):
        n, free, limit = bench_machine(name, dt_s, args.cycles, timed=False)
        _, timed, _ = bench_machine(name, dt_s, args.cycles, timed=True)
        print(f"| {name} | {n} | {free:.0f} steps/s | {timed:.0f} steps/s | {limit:.0f} Hz |")


if __name__ == "__main__":
    main()
