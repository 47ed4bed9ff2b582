"""A motorised rotary stage and a lamp relay behind a real pymodbus server (TCP, or RTU on a pty)."""
