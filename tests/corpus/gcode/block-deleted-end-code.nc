(expect: end-code 4)
G21 G90
G1 X10 F1500
/M30
