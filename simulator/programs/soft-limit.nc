%
O9001 (SOFT LIMIT TEST)
(drives X past +3000: alarm 1001 at line 7, before the axis moves)
N10 G21 G90 G17
N20 G0 Z10
N30 G0 X2900 Y750
N40 G1 X3050 F6000
N50 M30
%
