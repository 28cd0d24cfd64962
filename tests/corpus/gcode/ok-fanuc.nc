%
O2001 (BRACKET)
(expect: accepted)
(rules: {dialect: fanuc})
(name: O2001.nc)
G21 G90 G17
G0 X0 Y0
G1 X100 F1000
G4 P500
G2 X120 Y20 R20
M30
%
