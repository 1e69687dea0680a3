"""The controller's status (pure core, no rclpy): what ``controller/status`` says of a
``ControllerCore`` (controller.py) between cycles: its mode, the strategy and the
settings in force, the active drives, the tracking error and the statistics, the
faults and the cause of a stop.
"""

from __future__ import annotations

from .config import RUNTIME_SETTINGS
from .laws import error_norms

__all__ = ["OK", "WARN", "ERROR", "controller_status"]

OK, WARN, ERROR = 0, 1, 2        # diagnostic_msgs/DiagnosticStatus levels


def controller_status(core) -> tuple[int, str, dict]:
    """(level, message, values) of ``core``: ERROR once stopped (the reason), WARN
    when running on fewer drives (the faults), else OK with the mode."""
    r, sup, config = core.record, core.supervisor, core.config
    trans, angle = error_norms(r.error, core.space)
    values = {"mode": core.mode, "model": core.machine.model_label, "strategy": config.strategy, "distribution": config.distribution,
              "active_drives": ",".join(core.names[k] for k in sup.active),
              "tracking_error_m": trans, "max_tracking_error_m": core.max_error_m,
              "internal_force_norm_n": r.internal_force_norm_n, "peak_drive_force_n": core.peak_force_n,
              "saturation_count": sup.saturation_count, "cycles": core.cycles,
              "faults": "; ".join(sup.faults) or "none", "cause": str(sup.stop_cause),
              "feed_override": core.feed.target, "feed_scale": core.feed.scale, "dt_s": config.dt_s,
              **{name: getattr(config, name) for name in RUNTIME_SETTINGS}}
    if core.space.translation_axes < core.dof:
        values["tracking_error_rad"] = angle
    if sup.stopped:
        return ERROR, f"stopped: {sup.stop_reason}", values
    if sup.failed:
        return WARN, f"degraded: {'; '.join(sup.faults)}", values
    return OK, core.mode, values
