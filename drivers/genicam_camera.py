"""A machine-vision camera through Aravis: any GigE Vision or USB3 Vision camera, controlled by its
GenICam features (docs/camera.md).

* Features by their SFNC names — ``ExposureTime`` (µs), ``Gain`` (dB), ``BlackLevel``, ``PixelFormat``,
  ``TriggerSelector=FrameStart``, ``TriggerMode=On``, ``TriggerSource=Software``, ``TriggerSoftware``,
  ``AcquisitionMode=Continuous`` — and the older names a camera may have instead (``ExposureTimeAbs``;
  ``GainRaw``, in the camera's own units: ``gain_raw_per_db`` of them per dB).
* One frame per :meth:`GenICamCamera.capture`: a software trigger, then the buffer. A buffer that is
  incomplete (missing packets after the resends, a size mismatch) or that does not come within the
  exposure plus ``frame_timeout_s`` is never returned: :class:`~drivers.errors.ChecksumError` or
  :class:`~drivers.errors.DeviceTimeout`, which the acquisition's retry policy retakes. A camera that
  took control away (its heartbeat lost: the link was down longer than ``GevHeartbeatTimeout``) is a
  :class:`~drivers.errors.DeviceError` that no retry mends.
* The exposure and gain of each frame are those the camera reports: its chunks (``ChunkExposureTime``,
  ``ChunkGain``) where it sends them, else the features read back after setting them.
* GigE Vision: the packet size is negotiated with test packets (Aravis's ``gv_auto_packet_size``)
  unless ``packet_size`` is given; the stream's statistics (resent, missing packets) are logged at close.

Aravis comes from the system (Debian: ``gir1.2-aravis-0.8``) through PyGObject; this module imports it
when a camera is opened, so the rest of the project runs without it.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from drivers import pfnc
from drivers.errors import ChecksumError, DeviceError, DeviceFault, DeviceTimeout, LimitError
from drivers.protocols import RawFrame

log = logging.getLogger(__name__)
N_BUFFERS = 4
CHUNKS = ("ChunkExposureTime", "ChunkGain", "ChunkSimulatorTruth")  # the last: the simulated camera's
STREAM_STATISTICS = ("n_completed_buffers", "n_failures", "n_timeouts", "n_missing_frames",
                     "n_received_packets", "n_missing_packets", "n_resend_requests", "n_resent_packets",
                     "n_size_mismatch_errors", "n_underruns", "n_ignored_packets", "n_duplicated_packets",
                     "n_error_packets")  # fmt: skip


RMEM_MAX = Path("/proc/sys/net/core/rmem_max")  # Linux: the largest receive buffer a socket may ask for


def receive_buffer_cap() -> int | None:
    """The largest receive buffer (bytes) the kernel grants a UDP socket, ``net.core.rmem_max`` (read from
    :data:`RMEM_MAX`); None where it cannot be read (not Linux)."""
    try:
        return int(RMEM_MAX.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def short_buffer_advice(cap: int, frame_bytes: int) -> str:
    """What to do when a GigE Vision stream's socket cannot hold a whole frame: the packets that arrive
    while the receiving thread waits for a core, beyond ``cap`` bytes, are dropped and must be resent
    (measured in docs/camera.md: up to 320 of a frame's 826 packets at a 4 MiB cap, none at 16 MiB)."""
    room = 1 << max(frame_bytes - 1, 1).bit_length()  # the next power of two above a frame
    return (f"the kernel caps a socket's receive buffer at {cap:,} bytes (net.core.rmem_max), less than a "
            f"frame's {frame_bytes:,}: on a busy computer the rest of a frame is dropped and must be resent; "
            f"raise it: sudo sysctl -w net.core.rmem_max={room}")  # fmt: skip


class AravisMissing(DeviceError):
    """Aravis (or PyGObject) is not installed here."""


def aravis() -> Any:
    """The Aravis module (GObject introspection); :class:`AravisMissing` saying what to install if not."""
    try:
        import gi

        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis  # pyright: ignore[reportAttributeAccessIssue]  (a typelib)
    except (ImportError, ValueError) as exc:
        raise AravisMissing(
            f"Aravis is not available ({exc}); install it: apt-get install gir1.2-aravis-0.8 (Debian/Ubuntu) "
            "and pip install 'PyGObject<3.51' (scripts/setup does both)",
            device="GenICam camera",
        ) from exc
    return Aravis


@dataclass(frozen=True)
class GenICamConfig:
    """Which camera, how its frames come, and any feature to set as it opens."""

    device: str  # Aravis's device id ("Basler-21234567", as arv-tool-0.8 lists it) or an IP address
    pixel_format: str | None = None  # a PFNC name the camera offers (drivers.pfnc.FORMATS); None: its own
    features: dict[str, bool | int | float | str] = field(default_factory=dict)  # set once, in this order
    frame_timeout_s: float = 20.0  # past the exposure: a frame that has not arrived is lost
    packet_size: int | None = None  # GigE Vision bytes per packet; None: negotiated
    gain_raw_per_db: float | None = None  # only for a camera with GainRaw instead of Gain (dB)
    max_gain_db: float = 24.0


class GenICamCamera:
    """A :class:`~drivers.protocols.Camera` on Aravis, software-triggered, one raw frame at a time."""

    def __init__(self, config: GenICamConfig):
        if config.pixel_format is not None and config.pixel_format not in pfnc.FORMATS:
            raise LimitError(
                f"pixel format {config.pixel_format!r} is not one hlr-lab decodes; choose one of "
                + ", ".join(sorted(pfnc.FORMATS)),
                device=f"camera {config.device}",
            )
        self.config = config
        self.name = f"camera {config.device}"
        self._arv = aravis()
        self._control_lost = threading.Event()
        self._stream: Any = None
        self._chunk_parser: Any = None
        self._camera: Any = None  # Aravis's objects: typed by introspection at run time only
        self._device: Any = None
        try:
            self._camera = self._arv.Camera.new(config.device)
        except Exception as exc:  # GLib.Error: not found, no answer, the XML unreadable
            raise DeviceError(
                f"cannot open ({_message(exc)}); check the device id or address (arv-tool-0.8 lists the "
                "cameras it sees) and that no other program holds it",
                device=self.name,
            ) from exc
        self._device = self._camera.get_device()
        lost = self._control_lost  # the handler holds the event only: no cycle keeps Aravis's objects alive
        self._device.connect("control-lost", lambda *_: lost.set())
        try:
            self._take_control()
            self._configure()
        except BaseException:
            self.close()
            raise

    # -- set-up -------------------------------------------------------------------------------------

    def _take_control(self) -> None:
        """Hold the camera's control channel, waiting out a program that held it and ended without letting
        go (killed, crashed): the camera frees it after its heartbeat timeout."""
        if not self._camera.is_gv_device() or self._device.is_controller():
            return
        timeout_s = self._get("GevHeartbeatTimeout") / 1000 if self._has("GevHeartbeatTimeout") else 3.0
        log.info("%s: held by another program; waiting up to %.1f s for it to let go", self.name, timeout_s)
        deadline = time.monotonic() + timeout_s + 1.0
        while not self._took_control():
            if time.monotonic() > deadline:
                raise DeviceError(
                    "another program holds its control channel; close it (arv-viewer, another hlr-lab) and try "
                    "again",
                    device=self.name,
                )
            time.sleep(0.2)

    def _took_control(self) -> bool:
        try:
            return bool(self._device.take_control())
        except Exception:  # GLib.Error: access denied while the other program holds it
            return False

    def _configure(self) -> None:
        c = self.config
        if c.pixel_format is not None:
            self._set("PixelFormat", c.pixel_format)
        self.pixel_format = str(self._get("PixelFormat"))
        if self.pixel_format not in pfnc.FORMATS:
            raise DeviceFault(
                f"sends {self.pixel_format}, which hlr-lab does not decode; set pixel_format in [camera.genicam]",
                device=self.name,
                code=0,
            )
        self.width, self.height = self._get("Width"), self._get("Height")
        for name, value in (("TriggerSelector", "FrameStart"), ("TriggerMode", "On"), ("TriggerSource", "Software"),
                            ("AcquisitionMode", "Continuous")):  # fmt: skip
            self._set(name, value)
        # the chunks this camera can send, each switched on by name where it has SFNC's ChunkSelector (many
        # cameras start with them off); each frame reads those it carries
        self._chunks = [name for name in CHUNKS if self._has(name)] if self._has("ChunkModeActive") else []
        if self._chunks:
            self._set("ChunkModeActive", True)
            selectable = self._enumeration("ChunkSelector") if self._has("ChunkSelector") else []
            for name in self._chunks:
                if (entry := name.removeprefix("Chunk")) in selectable:
                    self._set("ChunkSelector", entry)
                    self._set("ChunkEnable", True)
            self._chunk_parser = self._camera.create_chunk_parser()
        for name, value in c.features.items():
            self._set(name, value)
        self._exposure_feature = "ExposureTime" if self._has("ExposureTime") else "ExposureTimeAbs"
        self._gain_feature = "Gain" if self._has("Gain") else "GainRaw" if self._has("GainRaw") else None
        self.exposure_s = self._get(self._exposure_feature) / 1e6
        self.gain_db = 0.0
        if self._camera.is_gv_device():
            if c.packet_size:
                self._camera.gv_set_packet_size(c.packet_size)
            else:
                self._camera.gv_auto_packet_size()
        self._payload = int(self._camera.get_payload())
        if self._camera.is_gv_device() and _on_loopback(c.device):
            # Aravis's packet socket, bound to the loopback interface, takes in other simulated cameras'
            # streams too (ignored packets, frames never completed): the plain UDP socket there
            self._camera.gv_set_stream_options(self._arv.GvStreamOption.PACKET_SOCKET_DISABLED)
        self._stream = self._camera.create_stream(None, None)
        if self._stream is None:
            raise DeviceError(
                "cannot open its stream (a firewall, or another program streaming)", device=self.name
            )
        if isinstance(self._stream, self._arv.GvStream):
            # a busy computer, not the camera, is what loses packets on a lab PC: a socket buffer that holds
            # a whole frame — which Aravis sets as the first frame begins, too late for that frame's own
            # packets — and resends that may bring back all that was dropped (Aravis's default: a quarter)
            self._stream.set_property("socket-buffer", self._arv.GvStreamSocketBuffer.AUTO)
            self._stream.set_property("packet-request-ratio", 1.0)
            if advice := self._short_buffer():
                log.warning("%s: %s", self.name, advice)
        for _ in range(N_BUFFERS):
            self._stream.push_buffer(self._arv.Buffer.new_allocate(self._payload))
        self._call(self._camera.start_acquisition)

    def _has(self, name: str) -> bool:
        try:
            return bool(self._camera.is_feature_available(name))
        except Exception:  # a feature whose availability cannot be read is one we do not use
            return False

    def _set(self, name: str, value: bool | int | float | str) -> None:
        if not self._has(name):
            raise DeviceFault(f"has no feature {name} (arv-tool-0.8 -n ID features lists its features)",
                              device=self.name, code=0)  # fmt: skip
        setter = {bool: self._camera.set_boolean, int: self._camera.set_integer, float: self._camera.set_float,
                  str: self._camera.set_string}[type(value)]  # fmt: skip
        try:
            setter(name, value)
        except Exception as exc:
            raise self._failure(f"refused {name} = {value!r} ({_message(exc)})", exc) from exc

    def _get(self, name: str) -> Any:
        node, gc = self._device.get_feature(name), self._arv
        getter = (self._camera.get_string if isinstance(node, gc.GcEnumeration)
                  else self._camera.get_boolean if isinstance(node, gc.GcBoolean)
                  else self._camera.get_float if isinstance(node, gc.GcFloat)
                  else self._camera.get_string if isinstance(node, gc.GcString)
                  else self._camera.get_integer)  # fmt: skip
        try:
            return getter(name)
        except Exception as exc:
            raise self._failure(f"cannot read {name} ({_message(exc)})", exc) from exc

    def _enumeration(self, name: str) -> list[str]:
        """The entries of enumeration ``name`` the camera offers now."""
        try:
            return list(self._camera.dup_available_enumerations_as_strings(name))
        except Exception as exc:
            raise self._failure(f"cannot read {name}'s entries ({_message(exc)})", exc) from exc

    def _failure(self, what: str, exc: BaseException) -> DeviceError:
        """A failed feature access as a device error: lost control and no answer are worth knowing apart."""
        if self._control_lost.is_set():
            return DeviceError(
                "the camera took control away (its heartbeat was lost: the link was down too long); check the "
                "cable and the camera, then resume the run",
                device=self.name,
            )
        if "timeout" in what.lower() or "timeout" in _message(exc).lower():
            return DeviceTimeout(f"{what}; is the camera hung or unplugged?", device=self.name)
        return DeviceFault(what, device=self.name, code=getattr(exc, "code", 0))

    def _call(self, method: Any, *args: Any) -> Any:
        try:
            return method(*args)
        except Exception as exc:
            raise self._failure(
                f"{getattr(method, '__name__', 'command')} failed ({_message(exc)})", exc
            ) from exc

    # -- the Camera protocol -----------------------------------------------------------------------

    def set_exposure(self, seconds: float) -> None:
        if not seconds > 0:
            raise LimitError(f"exposure {seconds} s must be positive", device=self.name)
        # the camera's own range, as its other roundings: the frame says what it used (Camera protocol)
        lo_us, hi_us = self._call(self._camera.get_float_bounds, self._exposure_feature)
        self._set(self._exposure_feature, float(np.clip(seconds * 1e6, lo_us, hi_us)))
        self.exposure_s = float(self._get(self._exposure_feature)) / 1e6  # what the camera made of it

    def set_gain(self, gain_db: float) -> None:
        if not 0 <= gain_db <= self.config.max_gain_db:
            raise LimitError(
                f"gain {gain_db} dB is outside [0, {self.config.max_gain_db:g}]", device=self.name
            )
        if self._gain_feature == "Gain":
            self._set("Gain", float(gain_db))
            self.gain_db = float(self._get("Gain"))
        elif self._gain_feature == "GainRaw" and self.config.gain_raw_per_db:
            self._set("GainRaw", round(gain_db * self.config.gain_raw_per_db))
            self.gain_db = float(self._get("GainRaw")) / self.config.gain_raw_per_db
        elif gain_db:
            raise LimitError(
                "has no Gain feature in dB; set gain_raw_per_db in [camera.genicam] for its GainRaw, or use 0 dB",
                device=self.name,
            )

    def capture(self) -> RawFrame:
        """Trigger one frame and wait for it (the exposure plus ``frame_timeout_s``)."""
        if self._control_lost.is_set():
            raise self._failure("lost control", RuntimeError())
        while (stale := self._stream.try_pop_buffer()) is not None:  # frames of an earlier, failed capture
            self._stream.push_buffer(stale)
        self._call(self._camera.software_trigger)
        wait_us = int((self.exposure_s + self.config.frame_timeout_s) * 1e6)
        buffer = self._stream.timeout_pop_buffer(wait_us)
        if buffer is None:
            if self._control_lost.is_set():
                raise self._failure("lost control", RuntimeError())
            raise DeviceTimeout(
                f"no frame {self.config.frame_timeout_s:g} s after the exposure; is the camera hung or unplugged?",
                device=self.name,
            )
        try:
            return self._frame(buffer)
        finally:
            self._stream.push_buffer(buffer)

    def _frame(self, buffer: Any) -> RawFrame:
        status = buffer.get_status()
        if status != self._arv.BufferStatus.SUCCESS:
            raise ChecksumError(
                f"frame incomplete ({status.value_nick}: packets lost beyond the resends); retaking it",
                device=self.name,
            )
        data = buffer.get_data()
        try:
            pixels = pfnc.decode(data, self.pixel_format, self.width, self.height)
        except ValueError as exc:
            raise ChecksumError(f"frame cut short ({exc})", device=self.name) from exc
        said = self._chunk_values(buffer)
        return RawFrame(
            pixels=pixels,
            bits=pfnc.FORMATS[self.pixel_format].bits,
            exposure_s=said["ChunkExposureTime"] / 1e6 if "ChunkExposureTime" in said else self.exposure_s,
            gain_db=said.get("ChunkGain", self.gain_db),
            captured_at=time.time(),
            meta=json.loads(said.get("ChunkSimulatorTruth") or "{}"),  # a simulated camera's account of it
        )

    def _chunk_values(self, buffer: Any) -> dict[str, Any]:
        """The chunks ``buffer`` carries, by feature name (one not sent with this frame is left out: the
        values read back after setting stand in for it)."""
        said: dict[str, Any] = {}
        for name in self._chunks:
            read = (
                self._chunk_parser.get_string_value
                if name == "ChunkSimulatorTruth"
                else self._chunk_parser.get_float_value
            )
            try:
                said[name] = read(buffer, name)
            except Exception:  # GLib.Error: the chunk is not in this frame
                continue
        return said

    def statistics(self) -> dict[str, int]:
        """The stream's counters since it opened (Aravis's names: resent and missing packets, …)."""
        if self._stream is None:
            return {}
        return {name: int(self._stream.get_info_uint64_by_name(name)) for name in STREAM_STATISTICS}

    def describe(self) -> dict[str, Any]:
        """What the camera says it is (for ``hlr-lab doctor``): vendor, model, serial, firmware, pixel
        formats, exposure (s), temperature (°C, if it has ``DeviceTemperature``); and what to do when the
        kernel's socket buffer cannot hold its frame (``receive_buffer_advice``)."""
        about: dict[str, Any] = {}
        for key, feature in (("vendor", "DeviceVendorName"), ("model", "DeviceModelName"),
                             ("serial", "DeviceSerialNumber"), ("firmware", "DeviceFirmwareVersion"),
                             ("temperature_c", "DeviceTemperature")):  # fmt: skip
            if self._has(feature):
                about[key] = self._get(feature)
        about["pixel_formats"] = list(
            self._device.dup_available_enumeration_feature_values_as_strings("PixelFormat")
        )
        about["pixel_format"] = self.pixel_format
        about["exposure_s"] = self.exposure_s
        if advice := self._short_buffer():
            about["receive_buffer_advice"] = advice
        return about

    def _short_buffer(self) -> str | None:
        """What to do when this GigE Vision camera's frame does not fit in the socket buffer the kernel
        allows (:func:`short_buffer_advice`); None when it fits, or the camera is not GigE Vision."""
        cap = receive_buffer_cap()
        if not self._camera.is_gv_device() or cap is None or cap >= self._payload:
            return None
        return short_buffer_advice(cap, self._payload)

    def close(self) -> None:
        """Stop acquiring, log the stream's statistics, release the camera (idempotent).

        Every Aravis object is let go here, so the camera is released now (its control given back, its
        threads joined) rather than whenever the garbage collector finds it: that would run in whatever
        thread allocates next, holding Python's lock for as long as a camera that is gone takes to not
        answer."""
        camera, self._camera = getattr(self, "_camera", None), None
        if camera is None:
            return
        if self._stream is not None:
            log.info("%s: stream %s", self.name, ", ".join(f"{k} {v}" for k, v in self.statistics().items()))
            try:
                camera.stop_acquisition()
            except Exception as exc:  # a camera already gone: nothing more to stop
                log.info("%s: stop acquisition: %s", self.name, _message(exc))
        self._stream = self._chunk_parser = self._device = None
        del camera


def _on_loopback(device: str) -> bool:
    """Whether ``device`` is an address on this computer (a simulated camera), not an id or a remote IP."""
    try:
        return ipaddress.ip_address(device).is_loopback
    except ValueError:  # a device id ("Basler-21234567")
        return False


def _message(exc: BaseException) -> str:
    return getattr(exc, "message", None) or str(exc) or type(exc).__name__
