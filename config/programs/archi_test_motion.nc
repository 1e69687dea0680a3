(ARCHI §4 test motion: a translation while the nacelle turns from pi/4 to pi/2,)
(then back; machine coordinates in mm, C in degrees, from the home pose x=1000, y=-400, C45)
G21 G90 G17
G1 F3000 X1100 Y-350 C90
G4 P0.1
G1 X1000 Y-400 C45
M2
