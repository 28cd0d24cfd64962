(expect: syntax 8:11)
(expect: end-code 8)
G21 G90
G0 X10 Y10
M3 S1000
G1 X50 F1500
G1 Y40
G1 X10 Y4 (second edge of the squa