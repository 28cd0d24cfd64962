(expect: end-code 7)
(a laser job whose post-processor forgot M30)
G21 G90
G0 X10 Y10
M3 S1000
G1 X50 F1500
M5
