(expect: character 3:18)
(rules: {dialect: linuxcnc})
G0 X10 Y10 (step – one)
M2
