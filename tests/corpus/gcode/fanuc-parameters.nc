%
O4001
(expect: syntax 6:1)
(rules: {dialect: fanuc})
(name: O4001.nc)
#1 = 25.0
G1 X50 F1500
M30
%
