%
; expect: forbidden-marker 1:1
; expect: forbidden-marker 7:1
; rules: {dialect: sinumerik}
; name: PART_1.MPF
G1 X50 F1500 M30
%
