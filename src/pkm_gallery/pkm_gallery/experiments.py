"""The papers' experiments of ``pkm-gallery``, one module per paper (archi, mom3,
sliding_star, orthoglide; hexapod: the papers' methods on 6-DOF machines and LinuxCNC's
hexapod), registered here in the order of docs/results.md. Each runs its scenario files
in one process and judges the measured figures against the paper's claim; the
thresholds are argued in the claim's text (docs/results.md shows them). The framework:
:mod:`pkm_gallery.framework`.
"""

from __future__ import annotations

from pkm_gallery import archi, calibration, hexapod, mom3, orthoglide, sliding_star
from pkm_gallery.framework import Experiment

MODULES = (archi, mom3, sliding_star, hexapod, orthoglide, calibration)
EXPERIMENTS: dict[str, Experiment] = {e.name: e for module in MODULES for e in module.EXPERIMENTS}

# the papers' experiments not run here yet, and why: (name, where in the paper, why),
# listed in results.md (none left: the last ones, MoM3 Table 3 and Sliding Star's
# on-line forward kinematics, are experiments above)
PENDING: tuple[tuple[str, str, str], ...] = ()
