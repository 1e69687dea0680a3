(hexapod_demo: LinuxCNC's genhexkins hexapod, machine coordinates in inches as its)
(config; A B C in degrees, rotations about the base x, y, z axes. A square in a tilted)
(plane, blended within 0.01 in, then a twist about z, and back home)
G20 G90 G64 P0.01
G1 F120 X1.0 Y0.0 Z20.0 A2.0 B-2.0
G1 X1.0 Y1.0 Z20.5 C3.0
G1 X-1.0 Y1.0 Z20.5 A-2.0
G1 X-1.0 Y-1.0 Z20.0 B2.0 C-3.0
G1 X0.0 Y0.0 Z20.0 A0.0 B0.0 C0.0
G4 P0.2
M2
