%
O1234 (FLANGE)
(expect: program-name 2)
(rules: {dialect: fanuc})
(name: O1235.nc)
G21 G90
G1 X50 F1500
M30
%
