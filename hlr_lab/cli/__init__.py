"""The ``hlr-lab`` command line (the composition root: the only place that may reach ``sim``)."""
