(MoM3: a 20 mm square in the horizontal plane at the home height, from the home position)
(x = 0, y = 0, z = 882 mm; machine coordinates in mm)
G21 G90
G1 F3000 X20 Y0 Z882
G1 X20 Y20
G1 X0 Y20
G1 X0 Y0
M2
