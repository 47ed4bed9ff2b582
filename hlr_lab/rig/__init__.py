"""The rig as a file describes it: the validated rig file, the gantry's kinematics, a calibrated copy written."""
