"""``hlr-lab report``: one self-contained HTML page per session (images embedded, no network)."""
