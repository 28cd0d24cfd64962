(expect: accepted)
(rules: {dialect: linuxcnc})
G20 G90 G17
#1 = 0.5
G0 X0 Y0 Z0.1
G1 Z-0.05 F20
G1 X2 Y1 F40
G2 X3 Y2 I0 J1 P2
G4 P0.5
G0 Z0.1
M2
