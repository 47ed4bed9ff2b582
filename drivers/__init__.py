"""The hardware edge of hlr-lab: device protocols and the drivers that satisfy them.

Nothing here imports the rest of the project; SDK types (dynamixel_sdk, pymodbus) never leave
this package, their result codes become the exceptions of :mod:`drivers.errors`.
"""
