(hexapod_metrology: hexapod8 from home to a pose turned about all three axes, and)
(held there; machine coordinates in mm, A B C in degrees)
G21 G90
G1 F3000 X30 Y-20 Z620 A3 B-2 C5
G4 P0.4
M2
