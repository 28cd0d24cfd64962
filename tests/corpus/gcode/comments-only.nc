(expect: empty -)
(this job lost its body somewhere)
; nothing but comments
