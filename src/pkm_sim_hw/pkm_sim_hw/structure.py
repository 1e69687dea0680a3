"""What a simulated machine's structure does to the tool, whatever moves the
platform (no rclpy): MoM3 §7.1's compliance, per task coordinate,
x_tool = x + C f_load + C_frame f_frame, the rigid pose deflected by the diagonal
compliance C under the external load and carried by the actuation chain's frame,
C_frame under the frame's load. Unseen by the drive encoders, seen by a metrology on
the tool (``plant.Plant``, ``strut_plant.StrutPlant``, ``rail_step``)."""

from __future__ import annotations

from pkm_kinematics.jit import kernel


@kernel()
def deflected(x, compliance, load, frame_compliance, frame_load):
    """One task coordinate of the tool: x + C f_load + C_frame f_frame."""
    return x + compliance * load + frame_compliance * frame_load
