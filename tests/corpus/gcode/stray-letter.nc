(expect: syntax 3:10)
G21 G90
G1 X10 Y F1500
M30
