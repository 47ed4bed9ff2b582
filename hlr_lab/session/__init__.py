"""The session directory that ``hlr-lab acquire`` writes (docs/sessions.md): an append-only journal, and raw
frames with sidecars, written so that a crash, a kill or a power cut loses nothing that counted."""
