(expect: character 3:7)
G21 G90
G0 X10 Y10
M30
