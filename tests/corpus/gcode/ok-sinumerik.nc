; expect: accepted
; rules: {dialect: sinumerik}
; name: PART_1.MPF
N10 G90 G71 G17
N20 G0 X0 Y0
N30 G1 X50 F2000 ; first edge
N40 G3 X60 Y10 I0 J10
N50 M30
