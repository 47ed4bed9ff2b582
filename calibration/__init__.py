"""Calibration procedures (camera, turntable axis, light position, radiometric) writing files the rig refers to."""
