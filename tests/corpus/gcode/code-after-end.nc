(expect: end-code 6)
(rules: {dialect: laser-sim})
G21 G90
G1 X10 F1500
M30
G0 X0 Y0
(a second program pasted after the first would never run)
