"""The workloads of ``hlr-lab bench``: each measures and returns figures; the command line prints them."""
