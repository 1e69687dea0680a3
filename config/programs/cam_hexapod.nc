%
(cam_hexapod: a part program in the style of a LinuxCNC post-processor for the genhexkins)
(hexapod - work offset, tool change, spindle, coolant, arcs in XY and XZ, a five-axis tilt)
(about the tool tip, a drilling cycle. mm; the first line is the setter's: the part 50 mm)
(below the platform's home, so that with the 50 mm tool the spindle starts at home.)
G10 L2 P1 X0 Y0 Z458
G90 G94 G17 G91.1
G21
T1 M6
G43 H1
S10000 M3
M7
G54 G0 X-20 Y-20 Z5
G1 Z0 F300
G1 X20 F900
G2 X20 Y20 I0 J20
G1 X-20
G18 G3 X0 Z0 I10 K0
G17 G0 Z5
(tilt the spindle about the tool tip)
G1 Z0 F300
G1 A5 F600
G1 B-5
G1 A0 B0
G0 Z5
G98 G81 X0 Y0 Z-3 R2 F200
G80
M9
M5
G49
M30
%
