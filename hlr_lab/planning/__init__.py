"""Highlight-priority light planning (paper §3.2, and what a real rig adds).

:func:`hlr_lab.planning.planner.plan_lights` is the entry point.
"""
