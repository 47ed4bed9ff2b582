"""A Dynamixel Protocol 2.0 servo bus, byte for byte, served on a pseudo-terminal (or any byte stream)."""
