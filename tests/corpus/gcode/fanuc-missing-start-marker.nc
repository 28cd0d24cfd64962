O1001 (BRACKET)
(expect: start-marker 1)
(rules: {dialect: fanuc})
(name: O1001.nc)
G21 G90
G0 X10 Y10
G1 X50 F1500
M30
%
