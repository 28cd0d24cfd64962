(expect: character 6:4)
(expect: syntax 8:4)
(expect: line-length 9:41)
(expect: end-code 10)
(rules: {max_line_length: 40})
G21 G90
G1 X10 F1500
G1 Q
(a comment that goes on for far too long for this controller)
G0 X0 Y0
