(expect: accepted)
(a small laser part: square with a round corner and a hole)
G21 G90 G17 G94
G0 X10 Y10 Z5
G1 Z0 F300
M3 S1500
G1 X60 F1200
G3 X70 Y20 I0 J10
G1 Y60
G1 X10
G1 Y10
M5
G0 X40 Y35
M3
G2 X40 Y35 I5 J0 F600
M5
G0 Z5
M30
