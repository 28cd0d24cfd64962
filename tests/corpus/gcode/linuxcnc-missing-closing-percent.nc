%
(expect: end-marker 6)
(rules: {dialect: linuxcnc})
G21 G90
G1 X10 F1500
M2
