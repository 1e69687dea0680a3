(Sliding Star: a rectangle 200 x 100 mm traced twice at 0.5 m/s while the platform)
(turns +-10 deg at its corners; machine coordinates in mm, C in degrees, from home 0, 0, C0)
G21 G90 G17
G1 F30000 X100 Y50 C10
G1 X-100 C-10
G1 Y-50 C10
G1 X100 C-10
G1 Y50 C10
G1 X-100 C-10
G1 Y-50 C10
G1 X100 C-10
G1 Y50 C10
G1 X0 Y0 C0
M2
