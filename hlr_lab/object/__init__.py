"""The object measured: its mesh, same-colour regions, the built-in procedural objects, ray casting on it."""
