(ARCHI: a test motion in the spirit of ARCHI section 4, a translation while the nacelle turns)
(from pi/4 to pi/2, low in the workspace, where a chain crosses its singularity: leg 2 in line)
(with the nacelle, the 3-leg sub-machine J_234 singular. Machine coordinates in mm, C in)
(degrees; the start pose is the home pose x=1000, y=-400, C45)
G21 G90 G17
G1 F6000 Y-600
G4 P0.1
G1 F3000 X1100 Y-500 C90
M2
