"""The simulated camera: Mitsuba 3 renders of the scene with hlr-lab's own Blinn-Phong BSDF, then a sensor."""
