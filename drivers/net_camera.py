"""A camera behind a TCP endpoint speaking one JSON line per request (the simulated rig's camera,
``sim/camera_server.py``; a small bridge gives any other camera the same face).

Request ``{"exposure_s": s, "gain_db": g}``; reply a JSON header line (width, height, channels, dtype,
meta) and the pixels as little-endian uint16, row by row, or ``{"error": "..."}``. A reply that stops
short, or none within the timeout, is a device error: a frame is never returned half-read.
"""

from __future__ import annotations

import json
import socket
import time

import numpy as np

from drivers.errors import DeviceError, DeviceFault, DeviceTimeout, LimitError
from drivers.protocols import RawFrame


class NetworkCamera:
    """A camera served over TCP by ``hlr-lab sim serve`` (the simulated rig's): a
    :class:`~drivers.protocols.Camera`. Its protocol is ``sim/camera_server.py``'s."""

    def __init__(self, address: str, *, reply_timeout_s: float = 20.0, max_gain_db: float = 24.0):
        """reply_timeout_s: how long after its exposure a frame may take to arrive (reading out,
        transferring; a simulated camera renders); past that the camera is taken as hung."""
        self.address = address
        self.max_gain_db = max_gain_db
        self.exposure_s = 0.01
        self.gain_db = 0.0
        self.reply_timeout_s = reply_timeout_s
        self._connect()

    def _connect(self) -> None:
        host, _, port = self.address.removeprefix("tcp://").rpartition(":")
        try:
            self._conn = socket.create_connection((host, int(port)), timeout=self.reply_timeout_s)
        except (OSError, ValueError) as exc:
            raise DeviceError(
                f"cannot connect ({exc}); check the camera address and that its server runs", device=self.name
            ) from exc
        self._reply = self._conn.makefile("rb")

    @property
    def name(self) -> str:
        return f"camera on {self.address}"

    def set_exposure(self, seconds: float) -> None:
        if not seconds > 0:
            raise LimitError(f"exposure {seconds} s must be positive", device=self.name)
        self.exposure_s = float(seconds)

    def set_gain(self, gain_db: float) -> None:
        if not 0 <= gain_db <= self.max_gain_db:
            raise LimitError(f"gain {gain_db} dB is outside [0, {self.max_gain_db:g}]", device=self.name)
        self.gain_db = float(gain_db)

    def capture(self) -> RawFrame:
        """One frame at the current exposure and gain. After any error the link is closed, and the next
        capture opens a new one: a reply read part-way would misalign every later frame.

        A link that drops or a frame that stops short is a :class:`DeviceTimeout` (worth retrying); a
        request the camera refuses is a :class:`DeviceFault` (not)."""
        if self._conn.fileno() < 0:
            self._connect()
        try:
            return self._exchange()
        except DeviceError:
            self.close()
            raise

    def _exchange(self) -> RawFrame:
        request = {"exposure_s": self.exposure_s, "gain_db": self.gain_db}
        try:
            self._conn.settimeout(self.reply_timeout_s + self.exposure_s)
            self._conn.sendall((json.dumps(request) + "\n").encode())
            header = json.loads(self._reply.readline() or b"null")
            if header is None:
                raise DeviceTimeout("the camera closed the link", device=self.name)
            if "error" in header:
                raise DeviceFault(
                    f"the camera refused the request: {header['error']}", device=self.name, code=0
                )
            shape = (header["height"], header["width"], header["channels"])
            size = int(np.prod(shape)) * 2
            data = self._reply.read(size)
        except TimeoutError as exc:
            raise DeviceTimeout(
                f"no frame {self.reply_timeout_s:g} s after the exposure; is the camera hung?",
                device=self.name,
            ) from exc
        except OSError as exc:
            raise DeviceTimeout(f"the link dropped ({exc})", device=self.name) from exc
        if len(data) != size:
            raise DeviceTimeout(f"the frame stopped after {len(data)} of {size} bytes", device=self.name)
        meta = header.get("meta", {})
        return RawFrame(
            pixels=np.frombuffer(data, dtype="<u2").reshape(shape).astype(np.uint16),
            bits=int(meta.get("bits", 16)),
            exposure_s=self.exposure_s,
            gain_db=self.gain_db,
            captured_at=time.time(),
            meta=meta,
        )

    def close(self) -> None:
        self._reply.close()
        self._conn.close()
