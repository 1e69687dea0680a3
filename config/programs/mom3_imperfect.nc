(MoM3 imperfect case: from home to a corner of the workspace, where the unequal)
(parallelogram bars tilt the platform most, and hold there; machine coordinates in mm)
G21 G90
G1 F3000 X100 Y-80 Z800
G4 P0.6
M2
