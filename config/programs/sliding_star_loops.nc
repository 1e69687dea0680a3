(Sliding Star: a rectangle 400 x 200 mm traced twice at 0.5 m/s while the platform)
(turns +-10 deg at its corners; machine coordinates in mm, C in degrees, from home 0, 0, C0)
G21 G90 G17
G1 F30000 X200 Y100 C10
G1 X-200 C-10
G1 Y-100 C10
G1 X200 C-10
G1 Y100 C10
G1 X-200 C-10
G1 Y-100 C10
G1 X200 C-10
G1 Y100 C10
G1 X0 Y0 C0
M2
