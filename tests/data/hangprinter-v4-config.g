; A RepRapFirmware config.g for a Hangprinter v4 with the reference configuration's
; calibrated values: three anchors near the floor, one on the ceiling, ODrives on CAN
; boards 40 to 43 and the standard spools, gears and pulley blocks.

; General
G21                             ; millimetres
G90                             ; absolute coordinates
M83                             ; relative extruder moves
M550 P"hp4-lab"                 ; machine name

; Motors: the anchors' ODrives, then the built-in drivers for the extruders
G4 S1
M584 X40.0 Y41.0 Z42.0 U43.0 P4
M584 E0:1:2:3:4:5

; Kinematics
M669 K6
M669 P2000.0                    ; print radius
M669 S430 T0.1                  ; segmentation
M669 A0:-1610.98:-131.53 B1314.22:1268.14:-121.28 C-1415.73:707.61:-121.82 D0:0:2299.83
M666 Q0.128181 R75.546:75.659:76.128:75.192

M208 Z2000.00                   ; highest Z, below the D anchor
M208 S1 Z-10.0                  ; lowest Z

M666 U2:2:2:4                   ; pulley blocks on A B C D
M666 O1:1:1:1                   ; one line per spool
M666 L20:20:20:20               ; motor gear teeth
M666 H255:255:255:255           ; spool gear teeth

; Flex compensation
M666 W1.0                       ; the mover weighs 1 kg
M666 S20000.0                   ; line spring constant per unit length
M666 I0.0:0.0:0.0:0.0           ; least planned force per direction
M666 X70.0:70.0:70.0:70.0       ; most planned force per direction
M666 T10.0                      ; target force

; Drives
M666 J25:25:25:25               ; full steps per motor revolution
M569 P0 S1
M569 P1 S1
M569 P40.0 S1                   ; A forwards
M569 P41.0 S1                   ; B forwards
M569 P42.0 S0                   ; C backwards
M569 P43.0 S0                   ; D backwards

; Speeds and accelerations
M201 X10000 Y10000 Z10000 U10000 E1000
M203 X36000 Y36000 Z36000 E3600
M204 P2000 T4000
M566 X240 Y240 Z1200 E1200

M906 E1400 I60
M574 X0 Y0 Z0

; Hot end, fan, tool
M308 S1 P"temp0" Y"thermistor" T100000 B3950
M950 H1 C"out1" T1
M307 H1 B0 S1.00
M143 H1 S280
M950 F0 C"out8"
M563 P0 D0 H1
G10 P0 S0 R0
M92 E415
T0
