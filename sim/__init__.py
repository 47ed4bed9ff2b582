"""The simulated world (Mitsuba-rendered camera, Dynamixel bus on a pty, Modbus turntable).

It is the ground truth that hlr-lab is checked against, so it never imports ``hlr_lab``.
"""
