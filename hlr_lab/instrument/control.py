"""Driving a rig from code: lock its links, open and connect its devices and camera, and on every exit
make it safe and confirm it. ``hlr-lab acquire`` and ``hlr-lab calibrate`` both stand on this.

Whatever ends the block once the devices are open (an error, Ctrl-C, a device fault, or nothing) the
safe state runs (:meth:`hlr_lab.instrument.devices.RigDevices.safe_state`), and an early end comes out as
:class:`RunStopped` carrying what the devices confirmed: one line saying why the run stopped and in
what state the rig was left. Its exit status is 130 for an operator's stop (a signal) with the rig
confirmed safe, and 1 otherwise: a rig not confirmed safe is an operator's problem, never an
"interrupted" like any other.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass

from drivers.protocols import Camera, Clock
from hlr_lab.errors import HlrLabError, InputError
from hlr_lab.instrument.devices import (
    Links,
    RigDevices,
    SafeState,
    open_camera,
    open_devices,
    rig_device_links,
)
from hlr_lab.instrument.instruments import Instruments
from hlr_lab.instrument.locks import hold_devices
from hlr_lab.rig.file import Rig
from hlr_lab.session.lamp import WALL_CLOCK

EXIT_INTERRUPTED = 130  # as hlr_lab.cli.main's: read there from RunStopped.exit_status
NO_OVERRIDES = Links()


class RunStopped(HlrLabError):
    """The run ended early. ``cause`` is why; ``safe`` what the devices confirmed of the safe state;
    ``exit_status`` 130 or 1 (see the module's docstring)."""

    def __init__(self, cause: BaseException, safe: SafeState):
        self.cause, self.safe = cause, safe
        interrupted = isinstance(cause, KeyboardInterrupt)
        why = f"stopped ({cause or 'interrupted'})" if interrupted else f"stopped: {cause}"
        state = ("the rig is safe: " if safe.ok else "") + safe.sentence()
        self.exit_status = EXIT_INTERRUPTED if interrupted and safe.ok else 1
        super().__init__(f"{why}. {state}. Run the same command again to resume.")


class _NoLampRelay:
    """The lamp of a rig file without a ``[lamp]`` section: off, and refusing to be switched on."""

    def __init__(self, rig_source: str):
        self.rig_source = rig_source

    def set(self, on: bool) -> None:
        if on:
            raise InputError(
                "this step switches the lamp on, and the rig file has no [lamp] section (its relay): add one "
                "(docs/rig.example.toml)",
                path=self.rig_source,
                field="lamp",
            )

    def get(self) -> bool:
        return False


@dataclass(frozen=True)
class OpenRig:
    """The rig's devices, connected and energised, its camera and its clock."""

    devices: RigDevices
    camera: Camera
    clock: Clock
    rig_source: str  # the rig file, for errors

    @property
    def instruments(self) -> Instruments:
        d = self.devices
        lamp = d.lamp if d.lamp is not None else _NoLampRelay(self.rig_source)
        return Instruments(d.stage, d.gantry, self.camera, lamp, (d.gantry,), self.clock)


@contextlib.contextmanager
def open_rig(rig: Rig, links: Links = NO_OVERRIDES) -> Iterator[OpenRig]:
    """Lock every device link of ``rig`` (:mod:`hlr_lab.instrument.locks`), open the devices and the camera, connect
    them; on exit the confirmed safe state, then the links released (see the module's docstring). An
    error before any device was opened (a busy link, a wrong address) comes out as it is."""
    devices: RigDevices | None = None
    try:
        with contextlib.ExitStack() as stack:
            stack.enter_context(hold_devices(rig_device_links(rig, links)))
            devices = stack.enter_context(
                open_devices(rig, gantry_port=links.gantry, stage_address=links.stage)
            )
            camera = open_camera(rig, links.camera)  # before anything is energised
            stack.callback(camera.close)
            devices.connect()
            yield OpenRig(devices, camera, links.clock or WALL_CLOCK, rig.source)
    except BaseException as exc:
        if devices is None or devices.safe is None:
            raise
        raise RunStopped(exc, devices.safe) from exc
    safe = devices.safe
    assert safe is not None  # leaving open_devices' block made the rig safe and recorded it
    if not safe.ok:
        raise RunStopped(HlrLabError("the run ended but the rig could not be made safe"), safe)
