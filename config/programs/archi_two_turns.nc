(ARCHI unlimited rotation: two full turns of the nacelle at x = 1 m, y = -0.4 m)
(machine coordinates in mm, C in degrees; the start pose is the home pose x=1000, y=-400, C45)
G21 G90 G17
G1 F3000 C765
M2
