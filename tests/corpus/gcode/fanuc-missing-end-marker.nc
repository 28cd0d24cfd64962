%
O1002 (BRACKET)
(expect: end-marker 8)
(rules: {dialect: fanuc})
(name: O1002)
G21 G90
G1 X50 F1500
M30
