(MoM3 Table 2 / Table 3: three measurement points P1-P3, each held 1.5 s while a load is)
(applied and removed; machine coordinates in mm, from the home position x=0, y=0, z=882)
G21 G90
G4 P1.5
G1 F3000 X60 Y0 Z882
G4 P1.5
G1 X-40 Y50 Z842
G4 P1.5
M2
