"""Servo drives behind the graph: CiA 402 over CANopen, virtual drives, homing."""
