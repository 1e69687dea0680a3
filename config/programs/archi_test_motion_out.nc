(ARCHI section 4 test motion, as the paper's Figure 11: a translation while the nacelle turns)
(from pi/4 to pi/2, one way; machine coordinates in mm, C in degrees, from the home pose)
(x=1000, y=-400, C45. archi_test_motion.nc also comes back.)
G21 G90 G17
G1 F3000 X1100 Y-350 C90
M2
