"""The instrument: devices built from the rig file, the rig opened and made safe, motion limits, locks, doctor."""
