"""The simulated camera as a GigE Vision device: GVCP control on UDP port 3956, a GenICam XML, GVSP
frames on the stream channel (docs/camera.md). Any GigE Vision client (Aravis's tools, the project's
GenICam driver) reaches it as it would a camera on the network."""
