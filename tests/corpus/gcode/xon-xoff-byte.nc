(expect: xon-xoff 4:10)
(rules: {dialect: laser-sim})
G21 G90
G1 X50 Y2 F1500
M30
