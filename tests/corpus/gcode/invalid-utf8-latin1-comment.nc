(expect: encoding 3:20)
G21 G90
G0 X10 Y10 (bend 90° here)
M30
