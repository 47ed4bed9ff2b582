"""From a session to per-region materials: HDR radiance per pose, the geometry of every pixel, sample
selection, and ``fit_region`` over all poses pooled (``hlr-lab fit``)."""
