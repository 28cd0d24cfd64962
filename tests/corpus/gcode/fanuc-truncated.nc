%
O3001
(expect: end-marker 8)
(expect: end-code 8)
(rules: {dialect: fanuc})
(name: O3001.nc)
G21 G90
G1 X50 F15