"""The simulated camera as a network endpoint, so drivers (and other processes) use it like a device.

Protocol, one TCP connection, requests in order:

* request: one JSON line, ``{"exposure_s": 0.01}``, optionally with ``"gain_db": 6.0``
* reply: one JSON line, ``{"width": W, "height": H, "channels": 3, "dtype": "uint16", "meta": {...}}``,
  then W·H·3 little-endian uint16 pixel values, row by row; or ``{"error": "..."}`` for a bad request.

``meta`` is what the simulator knows about the frame: where the axes were, the lamp, the exposure.
"""

from __future__ import annotations

import json
import logging
import socket
import threading

import numpy as np

from sim.camera import SimCamera

log = logging.getLogger(__name__)
MAX_GAIN_DB = 24.0  # a machine-vision sensor's analogue range
MAX_EXPOSURE_S = 3600.0  # as a plan's exposures


class CameraServer:
    def __init__(self, camera: SimCamera):
        self.camera = camera
        self._stop = threading.Event()
        self._server: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self.cut_replies = 0  # fault injection: this many next replies stop half-way and drop the link
        self.silent = False  # fault injection: requests are read and never answered (a hung camera)

    def serve_tcp(self, host: str = "127.0.0.1") -> str:
        self._server = socket.create_server((host, 0))
        self._server.settimeout(0.1)
        self._thread = threading.Thread(target=self._accept, name="sim-camera", daemon=True)
        self._thread.start()
        return f"{host}:{self._server.getsockname()[1]}"

    def _accept(self) -> None:
        server = self._server
        assert server is not None  # serve_tcp made it before starting this thread
        while not self._stop.is_set():
            try:
                conn, _ = server.accept()
            except (TimeoutError, OSError):
                continue
            try:
                self._serve(conn)
            except OSError as exc:  # the client went away mid-reply: serve the next one, as a camera would
                log.info("camera client gone (%s)", exc)
            except Exception:  # a bug in answering one request must not take the camera down for good
                log.exception("camera request failed; closing that link")
            finally:
                conn.close()

    def _serve(self, conn: socket.socket) -> None:
        with conn.makefile("rb") as requests:
            conn.settimeout(None)
            for line in requests:
                if self._stop.is_set():
                    break
                if self.silent:  # an injected fault: the camera hangs, answering nothing
                    self._stop.wait()
                    break
                reply = self._answer(line)
                if self.cut_replies > 0:  # an injected fault: half a reply, then the link drops
                    self.cut_replies -= 1
                    conn.sendall(reply[: len(reply) // 2])
                    break
                conn.sendall(reply)

    def _answer(self, line: bytes) -> bytes:
        try:
            request = json.loads(line)
            if not isinstance(request, dict):
                raise TypeError("a request is a JSON object")
            exposure, gain = float(request["exposure_s"]), float(request.get("gain_db", 0.0))
            if not 0 < exposure <= MAX_EXPOSURE_S:  # (NaN fails every comparison, so it is refused too)
                raise ValueError(f"exposure_s must lie in (0, {MAX_EXPOSURE_S:g}]")
            if not 0 <= gain <= MAX_GAIN_DB:
                raise ValueError(f"gain_db must lie in [0, {MAX_GAIN_DB:g}]")
        except (ValueError, KeyError, TypeError, OverflowError) as exc:
            return (
                json.dumps({"error": f'bad request ({exc}); send {{"exposure_s": seconds, "gain_db": dB}}'})
                + "\n"
            ).encode()
        frame, meta = self.camera.capture(exposure, gain)
        h, w, c = frame.shape
        header = {"width": w, "height": h, "channels": c, "dtype": "uint16", "meta": meta}
        return (json.dumps(header) + "\n").encode() + np.ascontiguousarray(frame, dtype="<u2").tobytes()

    def close(self) -> None:
        self._stop.set()
        if self._thread:
            self._thread.join(timeout=5)
        if self._server:
            self._server.close()
