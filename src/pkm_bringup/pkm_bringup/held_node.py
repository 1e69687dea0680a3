"""A node process started ahead of its run: ``python -m pkm_bringup.held_node <module>
--ros-args ...`` imports the node's module (rclpy, numpy, numba, its compiled kernels:
~1 s of CPU), then waits for one line on stdin: ``go`` runs the node (its module's
``main``, with the arguments that follow the module's name), anything else or the end
of stdin ends the process without having joined DDS.

pkm-run starts every node of a run this way before it looks for another run in the
domain (1 s of discovery it waits for anyway: graph.refuse_if_another_run), so that the
nodes' imports are done meanwhile, and releases them once the domain is its own
(processes.NodeProcess.release). A refused run's held nodes end without a word on DDS.
"""

from __future__ import annotations

import importlib
import sys


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        print("usage: python -m pkm_bringup.held_node <module> [--ros-args ...]", file=sys.stderr)
        return 2
    module = importlib.import_module(argv[0])
    if sys.stdin.readline().strip() != "go":
        return 0                             # the run did not start: nothing joined DDS
    sys.argv = [module.__file__, *argv[1:]]
    module.main()
    return 0


if __name__ == "__main__":
    sys.exit(main())
