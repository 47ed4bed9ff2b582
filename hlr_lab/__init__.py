"""hlr-lab: reflectance measurement with highlight-priority light planning."""

__version__ = "0.1.0"
