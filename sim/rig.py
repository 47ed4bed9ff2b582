"""The simulated rig's devices, started together: the gantry's servo bus, the turntable/lamp server and
(given a scene and a camera) the camera.

Endpoints are what real drivers open — a pseudo-terminal path, TCP ``host:port`` addresses — so the same
driver code runs against this and against the hardware. Everything stops on ``close`` (threads joined,
file descriptors and sockets closed).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from sim.camera import GantryGeometry, SimCamera, StageGeometry
from sim.clock import WorldClock
from sim.dynamixel.bus import SimBus
from sim.lamp import LampModel
from sim.render.camera import CameraSpec
from sim.render.scene import Patch, SceneSpec
from sim.render.sensor import SensorModel
from sim.turntable import register_map as rm
from sim.turntable.server import TurntableServer

GANTRY_IDS = (1, 2)  # azimuth, elevation
# the camera's link, bits a second: 10 GigE, as cameras of this frame size and depth come; a 1280 × 960 RGB
# frame of 16-bit words (7.4 MB) streams in 6 ms, where GigE's 61 ms would add a tenth to every photograph
CAMERA_LINK_BITS_PER_S = 10e9
GANTRY, STAGE = GantryGeometry(), StageGeometry()


@dataclass(frozen=True)
class Endpoints:
    dynamixel: str
    modbus: str
    servo_ids: tuple[int, ...]
    # the camera, when there is one: a GigE Vision device's address "127.0.0.N" (sim.gige), or the
    # "host:port" of a frame endpoint (sim.camera_server)
    camera: str | None = None
    stage_unit: int = rm.STAGE_UNIT
    lamp_unit: int = rm.RELAY_UNIT
    lamp_coil: int = rm.LAMP_COIL

    def as_dict(self) -> dict:
        d = {
            "dynamixel": self.dynamixel,
            "modbus": self.modbus,
            "servo_ids": list(self.servo_ids),
            "stage_unit": self.stage_unit,
            "lamp": {"unit": self.lamp_unit, "coil": self.lamp_coil},
        }
        if self.camera:
            d["camera"] = self.camera
        return d


class SimRig:
    """The simulated devices, and (given a scene and a camera) the camera that photographs them; a
    ``run_reference`` (a white reference on the plate) is added to that first scene, not to the targets
    :meth:`show` puts in front of the camera later.

    The camera is made last and imports the renderer only then, so a rig without a scene needs no Mitsuba.
    """

    def __init__(
        self,
        *,
        speed_factor: float = 1.0,
        servo_ids: tuple[int, ...] = GANTRY_IDS,
        scene: SceneSpec | None = None,
        camera: CameraSpec | None = None,
        sensor: SensorModel | None = None,
        lamp: LampModel | None = None,
        gantry: GantryGeometry = GANTRY,
        stage: StageGeometry = STAGE,
        spp: int = 16,
        seed: int = 0,
        run_reference: Patch | None = None,
        camera_link: Literal["gige", "network"] = "gige",
    ):
        """camera_link: how the camera is reached — a GigE Vision device on its own loopback address, as a
        lab's machine-vision camera is (through the GenICam driver), or the older frame endpoint."""
        # the arm rests horizontal along +x (its zero ticks), inside any sensible joint limits
        rest = dict(zip(servo_ids, gantry.zero_ticks, strict=False))  # a test may leave a servo out
        self.clock = WorldClock(speed_factor)  # the world's time (the lamp's, and a run's warm-up)
        self.bus = SimBus.with_servos(list(servo_ids), speed_factor=speed_factor, positions=rest)
        self.turntable = TurntableServer.simulated(speed_factor=speed_factor)
        self.camera: SimCamera | None = None
        self.camera_server = None
        self.gige = None
        try:
            host, port = self.turntable.serve_tcp()
            camera_endpoint = None
            if scene is not None and camera is not None:
                from sim.camera_server import CameraServer
                from sim.render.renderer import Renderer

                if run_reference is not None:  # it lies beside the object during runs
                    scene = replace(scene, patches=(*scene.patches, run_reference))
                self.camera = SimCamera(
                    Renderer(scene, camera, spp=spp),
                    sensor or SensorModel(),
                    self.bus,
                    self.turntable,
                    gantry,
                    stage,
                    seed,
                    lamp or LampModel(),
                    self.clock,
                )
                if camera_link == "gige":
                    self.gige = _gige_camera(self.camera, camera)
                    camera_endpoint = self.gige.address
                else:
                    self.camera_server = CameraServer(self.camera)
                    camera_endpoint = self.camera_server.serve_tcp()
            self.endpoints = Endpoints(
                self.bus.serve_pty(), f"{host}:{port}", tuple(servo_ids), camera_endpoint
            )
        except BaseException:
            self.close()
            raise

    def show(self, scene: SceneSpec) -> None:
        """Put another scene in front of the camera, as an operator moves a target between photographs
        (never during one: call it between captures)."""
        from sim.render.renderer import Renderer

        if self.camera is None:
            raise ValueError("this simulated rig has no camera: give it a scene and a camera to begin with")
        old = self.camera.renderer
        self.camera.renderer = Renderer(scene, old.camera, spp=old.spp)

    def close(self) -> None:
        """Stop every device (a second call does nothing: a test may pull the plug before the end)."""
        if getattr(self, "_closed", False):
            return
        self._closed = True
        if self.camera_server:
            self.camera_server.close()
        if self.gige:
            self.gige.close()
        self.bus.close()
        self.turntable.close()

    def __enter__(self) -> SimRig:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _gige_camera(camera: SimCamera, spec: CameraSpec):
    """``camera`` as a GigE Vision device on a loopback address of its own."""
    from sim.gige.device import GigECamera

    device = GigECamera(camera.capture, width=spec.width, height=spec.height, sensor_bits=camera.sensor.bits,
                        link_bits_per_s=CAMERA_LINK_BITS_PER_S)  # fmt: skip
    device.serve_on_loopback()
    return device
