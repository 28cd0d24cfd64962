(expect: syntax 3:12)
G21 G90
G0 X10 Y10 (rapid to the start
M30
