(expect: character 3:1)
G21 G90
G0 X10 Y10
M30
