%
(cam_orthoglide: a part program as a CAM post-processor for LinuxCNC writes it - a work)
(offset, a tool change, spindle and coolant, arcs in the three planes, drilling cycles -)
(for the Orthoglide. The first line is the setter's: where the part is, in machine mm.)
G10 L2 P1 X0 Y0 Z-40
(T1 D=6 CR=0 - flat end mill)
G90 G94 G17 G91.1
G21
G53 G0 Z0
T1 M6
S12000 M3
G54
M8
G0 X-30 Y-30
G43 Z15 H1
G0 Z5
G1 Z-2 F300
G1 X30 F1200
G3 X30 Y10 I0 J20
G1 X-30
G18 G3 X-10 Z-2 I10 K0
G19 G3 Y-10 Z-2 J-10 K0
G17 G0 Z5
(T2 D=3 - drill)
M9
M5
G53 G0 Z0
T2 M6
S8000 M3
M8
G43 H2
G98 G81 X-20 Y-20 Z-3 R2 F200
X0
X20
G80
G83 X20 Y20 Z-6 R2 Q2 F200
G80
M9
M5
G53 G0 Z0
G49
M30
%
