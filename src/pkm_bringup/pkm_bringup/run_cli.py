"""``pkm-run``'s command line, read before the orchestrator and what it imports (rclpy,
the kinematics' compiled kernels: over a second) are loaded, so that ``pkm-run --help``
and a refused argument answer at once. The run itself: orchestrator.run_command; a
run of processes starts the node server first (processes.start_node_server)."""

from __future__ import annotations

import argparse

from pkm_bringup.engines import ENGINES

__all__ = ["parser", "main"]


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="pkm-run", description="run a scenario end to end: every node, recording, "
                                                            "summary, report (pkm_bringup.orchestrator)")
    p.add_argument("scenario", help="scenario file, or the name of one in config/scenarios")
    p.add_argument("--in-process", action="store_true", help="all nodes in one executor")
    p.add_argument("--engine", choices=ENGINES, default="graph",
                   help="graph: the ROS 2 nodes (default); direct: the same loops in one process without a "
                        "transport, the same run bit for bit, several times faster (lockstep scenarios on "
                        "sim_hw only: pkm_bringup.direct)")
    p.add_argument("--runs", default="runs", help="parent of the run directory (default: runs)")
    p.add_argument("--run-dir", help="exact run directory (must not exist)")
    p.add_argument("--no-record", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--rt-profile", action="store_true",
                   help="realtime profile: SCHED_FIFO and locked memory for the loop's nodes "
                        "(the scenario key realtime_profile; needs root or CAP_SYS_NICE and CAP_IPC_LOCK)")
    p.add_argument("--credential", metavar="FILE",
                   help="the key the run's commands are signed with (mode 600; a panel's or a script's: "
                        "pkm_common.credential); default: a new one, RUN_DIR/credential.key")
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.engine == "graph" and not args.in_process:
        from pkm_bringup.processes import start_node_server, use_ros_environment
        use_ros_environment()           # the run's domain in the server's environment, and so in its nodes'
        start_node_server()             # the nodes' imports on the other core while this process does its own
    from pkm_bringup.orchestrator import run_command      # the heavy part, once the arguments are good
    return run_command(args)
