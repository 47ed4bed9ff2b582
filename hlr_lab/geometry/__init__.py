"""Numerical geometry: the camera model, the light sphere, silhouettes, colour spaces, clipping."""
