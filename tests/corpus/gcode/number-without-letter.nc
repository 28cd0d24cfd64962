(expect: syntax 3:8)
G21 G90
G1 X10 20 F1500
M30
