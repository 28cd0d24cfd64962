(expect: forbidden-code 4:8)
(rules: {forbid_codes: [M98]})
G21 G90
G1 X10 M98 P100
M30
