(expect: character 3:6)
(rules: {dialect: laser-sim})
G0 X1О Y10
M30
