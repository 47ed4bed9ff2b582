"""The simulated camera as a network endpoint, so drivers (and other processes) use it like a device.

Protocol, one TCP connection, requests in order:

* request: one JSON line, ``{"exposure_s": 0.01}``
* reply: one JSON line, ``{"width": W, "height": H, "channels": 3, "dtype": "uint16", "meta": {...}}``,
  then W·H·3 little-endian uint16 pixel values, row by row; or ``{"error": "..."}`` for a bad request.

``meta`` is what the simulator knows about the frame: where the axes were, the lamp, the exposure.
"""

from __future__ import annotations

import json
import socket
import threading

import numpy as np

from sim.camera import SimCamera


class CameraServer:
    def __init__(self, camera: SimCamera):
        self.camera = camera
        self._stop = threading.Event()
        self._server: socket.socket | None = None
        self._thread: threading.Thread | None = None

    def serve_tcp(self, host: str = "127.0.0.1") -> str:
        self._server = socket.create_server((host, 0))
        self._server.settimeout(0.1)
        self._thread = threading.Thread(target=self._accept, name="sim-camera", daemon=True)
        self._thread.start()
        return f"{host}:{self._server.getsockname()[1]}"

    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except (TimeoutError, OSError):
                continue
            with conn, conn.makefile("rb") as requests:
                conn.settimeout(None)
                for line in requests:
                    if self._stop.is_set():
                        break
                    conn.sendall(self._answer(line))

    def _answer(self, line: bytes) -> bytes:
        try:
            exposure = float(json.loads(line)["exposure_s"])
            if not exposure > 0:
                raise ValueError("exposure_s must be positive")
        except (ValueError, KeyError, TypeError) as exc:
            return (
                json.dumps({"error": f'bad request ({exc}); send {{"exposure_s": seconds}}'}) + "\n"
            ).encode()
        frame, meta = self.camera.capture(exposure)
        h, w, c = frame.shape
        header = {"width": w, "height": h, "channels": c, "dtype": "uint16", "meta": meta}
        return (json.dumps(header) + "\n").encode() + np.ascontiguousarray(frame, dtype="<u2").tobytes()

    def close(self) -> None:
        self._stop.set()
        if self._thread:
            self._thread.join(timeout=5)
        if self._server:
            self._server.close()
