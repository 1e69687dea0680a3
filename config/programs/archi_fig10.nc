(ARCHI Figure 10 path: at x = 1 m, y = -0.4 m the nacelle turns from -200 to 200 deg)
(machine coordinates in mm, C in degrees; the start pose is the home pose x=1000, y=-400, C45)
G21 G90 G17
G1 F3000 C-200
G4 P0.1
G1 C200
M2
