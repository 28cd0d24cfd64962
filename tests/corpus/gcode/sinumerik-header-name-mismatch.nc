%_N_PART_2_MPF
; expect: program-name 1
; rules: {dialect: sinumerik, markers: optional, program_name: must-match}
; name: PART_1.MPF
G1 X10 F1500
M30
%
