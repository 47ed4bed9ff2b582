"""The simulated worlds hlr-lab is run against, composed from its plan and rig files (the only code that
builds both sim and hlr_lab types; imported by the command line and the benchmarks only)."""
