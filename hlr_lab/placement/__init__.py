"""Where the object really lies on the plate, measured from photographs (docs/placement.md).

``photographs.py`` turns a view's frames into what registration compares (the object's mask) and says
where the lamps of a view stand; ``pose.py`` the six numbers of a placement and the matrix they make;
``solve.py`` the search over turns about the axis and the fit on the outlines. Pure functions on arrays:
the views are photographed by their callers (the simulated world's: ``worlds/placement_views.py``).
"""
