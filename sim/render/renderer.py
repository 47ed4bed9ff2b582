"""Rendering the simulated camera's view: one Mitsuba scene, loaded once, re-rendered per frame.

Per frame only the turntable angle (vertex positions and normals of every region), the light position
or direction and the lamp (on/off) change, through ``mi.traverse`` — Mitsuba users report time and memory
growing when scenes are reloaded per frame. Only the object's bounding box on the film is rendered: the
scene holds nothing else, so every other pixel is exactly zero (measured: half the time per frame).
"""

from __future__ import annotations

import numpy as np

from sim.render.camera import CameraFilm, CameraSpec
from sim.render.llvm import load_mitsuba
from sim.render.scene import SceneSpec


class Renderer:
    def __init__(
        self,
        scene: SceneSpec,
        camera: CameraSpec,
        *,
        spp: int = 16,
        integrator: str = "direct",
        max_depth: int = 4,
    ):
        self.mi = mi = load_mitsuba()
        from sim.render import opencv_sensor, phong

        phong.register()
        opencv_sensor.register()
        self.spec, self.camera, self.spp = scene, camera, spp
        self.film = CameraFilm(camera)
        m = scene.mesh_to_turntable
        vertices = scene.vertices @ m[:3, :3].T + m[:3, 3]
        normals = scene.vertex_normals() @ np.linalg.inv(m[:3, :3])
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        self._parts = []
        shapes = {}
        if scene.region_texture is not None:  # the material varies per texel: one shape, a region-map BSDF
            shapes["object"] = self._mesh(
                "object", scene.faces, vertices, normals, self._region_map_bsdf(scene), uv=scene.vertex_uv
            )
        else:  # one shape per region: each region's material is its own BSDF
            for r, material in enumerate(scene.materials):
                faces = scene.faces[scene.face_region == r]
                if len(faces):
                    bsdf = mi.load_dict(
                        {
                            "type": phong.PLUGIN,
                            "rd": list(material.rd),
                            "rs": list(material.rs),
                            "n": material.n,
                        }
                    )
                    shapes[f"region_{r}"] = self._mesh(f"region_{r}", faces, vertices, normals, bsdf)
        for i, patch in enumerate(scene.patches):  # already in the turntable frame; turned like the object
            matte = {"type": phong.PLUGIN, "rd": list(patch.reflectance), "rs": [0.0] * 3, "n": 1.0}
            bsdf = mi.load_dict(matte)
            quad = np.array([[0, 1, 2], [0, 2, 3]])
            up = np.tile([0.0, 0.0, 1.0], (4, 1))
            shapes[f"patch_{i}"] = self._mesh(f"patch_{i}", quad, patch.corners(), up, bsdf)
        for i, ball in enumerate(scene.mirror_balls):  # placed (and turned with the table) in render()
            bsdf = {"type": "roughconductor", "material": "Al", "alpha": ball.alpha}
            shapes[f"ball_{i}"] = {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "bsdf": bsdf}
        # L convention: a white Lambertian facing the light reads Φ/d² (point) or Φ (directional)
        strength = float(np.pi * scene.power)
        if scene.light == "point":
            light = {
                "type": "point",
                "position": [0.0, 0.0, 1.0],
                "intensity": {"type": "rgb", "value": [strength] * 3},
            }
        else:
            light = {
                "type": "directional",
                "direction": [0.0, 0.0, -1.0],
                "irradiance": {"type": "rgb", "value": [strength] * 3},
            }
        # BSDF-sampled rays cannot hit a point or directional light (delta emitters): light sampling only
        integ = (
            {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0}
            if integrator == "direct"
            else {"type": "path", "max_depth": max_depth}
        )
        self.scene = mi.load_dict(
            {
                "type": "scene",
                "integrator": integ,
                "sensor": self.film.sensor_dict(spp),
                "light": light,
                **shapes,
            }
        )
        self._params = mi.traverse(self.scene)
        self._strength = strength
        self._angle = None
        self._crop = (0, 0, self.film.width, self.film.height)

    def _mesh(self, name, faces, vertices, normals, bsdf, uv=None):
        """A Mitsuba mesh of ``faces`` (indices into the whole mesh's vertices), remembered for rotation."""
        mi = self.mi
        used, local = np.unique(faces, return_inverse=True)
        props = mi.Properties()
        props["bsdf"] = bsdf
        mesh = mi.Mesh(
            name,
            len(used),
            len(faces),
            props=props,
            has_vertex_normals=True,
            has_vertex_texcoords=uv is not None,
        )
        params = mi.traverse(mesh)
        params["faces"] = mi.UInt32(local.astype(np.uint32).ravel())
        params["vertex_positions"] = mi.Float(vertices[used].astype(np.float32).ravel())
        params["vertex_normals"] = mi.Float(normals[used].astype(np.float32).ravel())
        if uv is not None:
            # Mitsuba's texture v runs down the image; the scene's (OBJ) v runs up
            params["vertex_texcoords"] = mi.Float(
                np.column_stack([uv[used, 0], 1 - uv[used, 1]]).astype(np.float32).ravel()
            )
        params.update()
        self._parts.append((name, vertices[used].astype(np.float32), normals[used].astype(np.float32)))
        return mesh

    def _region_map_bsdf(self, scene: SceneSpec):
        mi = self.mi
        from sim.render import phong

        assert scene.region_texture is not None  # only a textured scene's regions come from a map
        index_image = scene.region_texture.astype(np.float32)[..., None]
        region_map = mi.load_dict(
            {
                "type": "bitmap",
                "bitmap": mi.Bitmap(index_image),
                "filter_type": "nearest",
                "raw": True,
                "wrap_mode": "repeat",
            }
        )
        table = lambda f: mi.Float([float(x) for m in scene.materials for x in np.atleast_1d(f(m))])  # noqa: E731
        return mi.load_dict(
            {
                "type": phong.MAP_PLUGIN,
                "region_map": region_map,
                "rd_table": table(lambda m: m.rd),
                "rs_table": table(lambda m: m.rs),
                "n_table": table(lambda m: m.n),
            }
        )

    def render(
        self, turntable_deg: float, light: np.ndarray, *, lamp_on: bool = True, seed: int = 0
    ) -> np.ndarray:
        """(H, W, 3) float32 radiance in the project's L units. ``light`` is the lamp's world position
        (point light) or the direction the light travels (directional)."""
        mi, p = self.mi, self._params
        if self._angle != turntable_deg:
            a = np.radians(turntable_deg)
            rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]], np.float32)
            for name, vertices, normals in self._parts:
                p[f"{name}.vertex_positions"] = mi.Float((vertices @ rot.T).ravel())
                p[f"{name}.vertex_normals"] = mi.Float((normals @ rot.T).ravel())
            points = [v @ rot.T for _, v, _ in self._parts]  # what the crop must hold
            for i, ball in enumerate(self.spec.mirror_balls):
                centre = rot @ np.asarray(ball.centre, np.float64)
                p[f"ball_{i}.to_world"] = mi.Transform4f().translate(centre.tolist()).scale(ball.radius)
                points.append(centre + ball.radius * _CUBE)
            self._crop = self.film.object_box(np.concatenate(points))
            p["sensor.film.crop_offset"] = mi.ScalarPoint2u(*self._crop[:2])
            p["sensor.film.crop_size"] = mi.ScalarVector2u(*self._crop[2:])
            self._angle = turntable_deg
        xyz = [float(x) for x in light]
        if self.spec.light == "point":
            p["light.position"] = mi.Point3f(*xyz)
            p["light.intensity.value"] = mi.Color3f([self._strength if lamp_on else 0.0] * 3)
        else:
            p["light.to_world"] = mi.Transform4f().look_at(origin=[0, 0, 0], target=xyz, up=_up(xyz))
            p["light.irradiance.value"] = mi.Color3f([self._strength if lamp_on else 0.0] * 3)
        p.update()
        crop = np.asarray(mi.render(self.scene, seed=seed, spp=self.spp), dtype=np.float32)
        # the scene holds only the object (and patches): outside their box the image is exactly 0 (box filter)
        x, y, w, h = self._crop
        image = np.zeros((self.film.height, self.film.width, 3), np.float32)
        image[y : y + h, x : x + w] = crop
        return image


_CUBE = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)  # a ball's box


def _up(direction) -> list[float]:
    d = np.asarray(direction, float)
    return [0.0, 1.0, 0.0] if abs(d[2]) > 0.9 * np.linalg.norm(d) else [0.0, 0.0, 1.0]
