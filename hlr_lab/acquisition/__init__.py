"""Acquisition: the pose loop, a run with its session, the white reference beside the object."""
