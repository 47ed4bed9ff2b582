"""Where the object really lies on the plate, measured from photographs (docs/placement.md).

``photographs.py`` turns a view's frames into what registration compares (the object's mask, its colour
per pixel); ``pose.py`` the six numbers of a placement and the matrix they make; ``solve.py`` the search
over rotations about the axis and the refinement on silhouettes and region borders. Pure functions on
arrays: the capture and the command live above (``hlr_lab.pipeline``, ``hlr_lab.cli.register_cmd``).
"""
