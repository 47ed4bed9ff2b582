"""The ground truth of the simulated world: a mesh split into regions with true (rd, rs, n), a light.

Only the simulator reads it. From a scene file (TOML, beside its mesh)::

    [object]
    mesh = "bunny8.ply"          # relative to this file; vertex colours or a texture
    texture = "tex.png"          # optional
    placed = { translation_m = [0.002, -0.0015, 0.03], rotation_deg = [0, 0, 3] }   # optional: where it lies
    [[region]]
    color = [205, 60, 40]        # 8-bit sRGB as stored; faces (texels, if textured) take the nearest listed colour
    rd = [0.62, 0.18, 0.12]      # linear reflectances; rd is NOT derived from the colour
    rs = [0.20, 0.20, 0.20]
    n = 80.0
    [light]
    type = "point"               # or "directional"
    power = 1.0                  # Φ

``placed`` is where the object really lies: the mesh → turntable transform, R = Rz·Ry·Rx (degrees, see
:func:`pose_matrix`) then the translation (metres). Without it the composition root puts the object where
the plan says (``SceneSpec.placed`` False); hlr-lab never reads it.

or programmatically (:class:`SceneSpec`), e.g. by the composition root from a plan's mesh and regions.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from trimesh.visual import ColorVisuals, TextureVisuals

from sim.tuples import triple


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class Material:
    rd: tuple[float, float, float]
    rs: tuple[float, float, float]
    n: float


@dataclass(frozen=True)
class MirrorBall:
    """A polished metal ball (Mitsuba's rough conductor, aluminium, GGX ``alpha``: a real mirror ball is
    never perfect, and a point lamp's reflection in a perfect one would be a single point no camera
    samples). Its centre is in the turntable frame, metres; it turns with the turntable."""

    centre: tuple[float, float, float]
    radius: float
    alpha: float = 0.01


@dataclass(frozen=True)
class Patch:
    """A flat Lambertian square lying on the plate (a white reference): its centre (x, y) in the turntable
    frame, its side and its face's height above the plate (metres), its reflectance per channel. It turns
    with the turntable."""

    centre_xy: tuple[float, float]
    size: float
    height: float
    reflectance: tuple[float, float, float]

    def corners(self) -> np.ndarray:
        """(4, 3) counter-clockwise seen from above (its face looks up, +z), at its true height: a scene
        with patches has no plate for it to flicker against."""
        x, y, h, z = *self.centre_xy, self.size / 2, self.height
        return np.array([[x - h, y - h, z], [x + h, y - h, z], [x + h, y + h, z], [x - h, y + h, z]])


@dataclass(frozen=True, eq=False)
class SceneSpec:
    """vertices (V, 3) and faces (F, 3) of the mesh in its own frame; face_region (F,) index into
    ``materials``; mesh_to_turntable (4, 4); the light's type and power Φ.

    A textured scene also has ``vertex_uv`` (V, 2) (OBJ convention, v up) and ``region_texture`` (H, W)
    region indices per texel: the renderer then takes the material per texel, so region borders may cross
    faces. ``normals`` (V, 3) overrides the area-weighted vertex normals (a textured mesh's vertices are
    split at UV seams, but its normals must not be).
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_region: np.ndarray
    materials: list[Material]
    mesh_to_turntable: np.ndarray
    light: str = "point"
    power: float = 1.0
    vertex_uv: np.ndarray | None = None
    region_texture: np.ndarray | None = None
    normals: np.ndarray | None = None
    mirror_balls: tuple[MirrorBall, ...] = ()
    patches: tuple[Patch, ...] = ()  # white references beside the object, on the plate
    placed: bool = False  # mesh_to_turntable is where the scene says the object lies (not a default)

    def vertex_normals(self) -> np.ndarray:
        return self.normals if self.normals is not None else _area_normals(self.vertices, self.faces)


def _area_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    acc = np.zeros_like(v)
    for corner in range(3):
        np.add.at(acc, f[:, corner], cross)
    return acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)


def _welded_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Normals of vertices split at UV seams, computed as if the copies were one vertex."""
    scale = max(float(np.ptp(v, axis=0).max()), 1e-12)
    _, first, inverse = np.unique(
        np.round(v / (scale * 1e-9)), axis=0, return_index=True, return_inverse=True
    )
    inverse = inverse.ravel()
    return _area_normals(v[first], inverse[f])[inverse]


def pose_matrix(translation=(0.0, 0.0, 0.0), rotation_deg=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4×4 from a translation (metres) and x, y, z rotations (degrees, applied in that order: R = Rz·Ry·Rx),
    the rotation first: p' = R p + t."""
    rx, ry, rz = np.radians(rotation_deg)
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    r = (
        np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
        @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
        @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    )
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, translation
    return m


def load_scene(path: str | Path) -> SceneSpec:
    """Read a scene file (module docstring); any field missing, of the wrong type or out of range, and a
    mesh or texture that cannot be read, is one :class:`SceneError` naming the file and the field."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SceneError(f"{path}: cannot read the scene ({exc})") from exc
    _known(data, {"object", "light", "region"}, path, "")
    obj = _table(data, "object", path)
    if "pose" in obj:  # the old key, which every world ignored: a file relying on it must hear so
        raise SceneError(
            f"{path}: object.pose: no longer read; where the object lies is "
            "object.placed = { translation_m = [x, y, z], rotation_deg = [rx, ry, rz] }"
        )
    _known(obj, {"mesh", "texture", "placed"}, path, "object")
    light = _known(_table(data, "light", path, required=False), {"type", "power"}, path, "light")
    regions = data.get("region", [])
    if not isinstance(regions, list) or not regions or not all(isinstance(r, dict) for r in regions):
        raise SceneError(f"{path}: region: at least one [[region]] table is needed")
    for i, r in enumerate(regions):
        _known(r, {"color", "rd", "rs", "n"}, path, f"region[{i}]")
    mesh_path = path.parent / _text(obj, "mesh", path, "object.mesh")
    texture = path.parent / _text(obj, "texture", path, "object.texture") if "texture" in obj else None
    placed = _table(obj, "placed", path, required=False, where="object.placed")
    _known(placed, {"translation_m", "rotation_deg"}, path, "object.placed")
    placement = pose_matrix(
        _numbers(placed.get("translation_m", [0, 0, 0]), 3, path, "object.placed.translation_m", bound=10.0),
        _numbers(placed.get("rotation_deg", [0, 0, 0]), 3, path, "object.placed.rotation_deg", bound=3600.0),
    )
    palette = np.array(
        [
            _numbers(r.get("color"), 3, path, f"region[{i}].color", low=0, high=255)
            for i, r in enumerate(regions)
        ]
    )
    materials = [_material(r, i, path) for i, r in enumerate(regions)]
    kind = light.get("type", "point")
    if kind not in ("point", "directional"):
        raise SceneError(f'{path}: light.type: "point" or "directional", not {kind!r}')
    (power,) = _numbers(
        [light.get("power", 1.0)], 1, path, "light.power", low=1e-9, high=1e9
    )  # a lamp that shines
    try:
        mesh = trimesh.load(mesh_path, process=False, force="mesh")
        assert isinstance(mesh, trimesh.Trimesh)  # force="mesh" concatenates a scene into one
        faces = np.asarray(mesh.faces, np.int64)
        vertices = np.asarray(mesh.vertices, np.float64)
        face_colour = _face_colours(mesh, faces, texture)
        uv = region_texture = normals = None
        if isinstance(mesh.visual, TextureVisuals):  # (_face_colours refused a texture without UVs)
            image = np.asarray(
                (Image.open(texture) if texture else _material_image(mesh.visual)).convert("RGB")
            )
            region_texture = _nearest(image.reshape(-1, 3).astype(np.float64), palette).reshape(
                image.shape[:2]
            )
            uv = np.asarray(mesh.visual.uv, np.float64)
    except Exception as exc:  # trimesh and PIL raise many types for a file they cannot read
        raise SceneError(
            f"{path}: object.mesh: cannot read {mesh_path.name} with its colours ({type(exc).__name__}: {exc})"
        ) from exc
    if len(faces) == 0 or not np.isfinite(vertices).all():
        raise SceneError(
            f"{path}: object.mesh: {mesh_path.name} has no faces, or coordinates that are not finite"
        )
    if uv is not None:
        normals = _welded_normals(vertices, faces)
    region = _nearest(face_colour, palette)
    return SceneSpec(vertices, faces, region, materials, placement, kind, power, uv, region_texture, normals,
                     placed="placed" in obj)  # fmt: skip


def _table(data: dict, key: str, path: Path, *, required: bool = True, where: str | None = None) -> dict:
    value = data.get(key)
    if value is None and not required:
        return {}
    if not isinstance(value, dict):
        raise SceneError(
            f"{path}: {where or key}: a table is needed" + ("" if value is None else f", not {value!r}")
        )
    return value


def _known(table: dict, keys: set[str], path: Path, where: str) -> dict:
    """``table`` if it holds only ``keys``: a misspelt key would otherwise leave its default in place."""
    unknown = sorted(set(table) - keys)
    if unknown:
        at = f"{where}.{unknown[0]}" if where else unknown[0]
        raise SceneError(f"{path}: {at}: not a key of a scene file here (known: {', '.join(sorted(keys))})")
    return table


def _text(table: dict, key: str, path: Path, where: str) -> str:
    value = table.get(key)
    if not isinstance(value, str) or not value:
        raise SceneError(f"{path}: {where}: a file name (text) is needed")
    return value


def _numbers(value, count: int, path: Path, where: str, *, low: float = -math.inf, high: float = math.inf,
             bound: float | None = None) -> list[float]:  # fmt: skip
    """``value`` as ``count`` finite numbers within [low, high] (or ±bound), else a SceneError for ``where``."""
    if bound is not None:
        low, high = -bound, bound
    ok = (
        isinstance(value, list)
        and len(value) == count
        and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
        and all(math.isfinite(v) and low <= v <= high for v in value)
    )
    if not ok:
        raise SceneError(
            f"{path}: {where}: {count} finite number(s) in [{low:g}, {high:g}] are needed, not {value!r}"
        )
    return [float(v) for v in value]


def _material(r: dict, i: int, path: Path) -> Material:
    rd = _numbers(r.get("rd"), 3, path, f"region[{i}].rd", low=0, high=1)  # reflectances: linear, in [0, 1]
    rs = _numbers(r.get("rs"), 3, path, f"region[{i}].rs", low=0, high=1)
    (n,) = _numbers(
        [r.get("n")], 1, path, f"region[{i}].n", low=1e-6, high=1e5
    )  # a Phong exponent is positive
    return Material(triple(rd), triple(rs), n)


def _nearest(colours: np.ndarray, palette: np.ndarray) -> np.ndarray:
    """(N,) index of the nearest palette colour for (N, 3) colours."""
    return np.argmin(((colours[:, None, :] - palette[None]) ** 2).sum(axis=2), axis=1)


def _face_colours(mesh: trimesh.Trimesh, faces: np.ndarray, texture: Path | None) -> np.ndarray:
    visual = mesh.visual
    if isinstance(visual, TextureVisuals) or texture is not None:
        if not isinstance(visual, TextureVisuals):
            raise ValueError("a texture was given but the mesh has no UV coordinates")
        image = np.asarray((Image.open(texture) if texture else _material_image(visual)).convert("RGB"))
        uv = np.asarray(visual.uv)[faces].mean(axis=1)
        h, w = image.shape[:2]
        col = np.clip((np.mod(uv[:, 0], 1) * w).astype(int), 0, w - 1)
        row = np.clip(((1 - np.mod(uv[:, 1], 1)) * h).astype(int), 0, h - 1)
        return image[row, col].astype(np.float64)
    if isinstance(visual, ColorVisuals) and visual.kind == "face":
        return np.asarray(visual.face_colors)[:, :3].astype(np.float64)
    if isinstance(visual, ColorVisuals) and visual.kind == "vertex":
        return np.asarray(visual.vertex_colors)[:, :3][faces].mean(axis=1).astype(np.float64)
    return np.zeros((len(faces), 3))


def _material_image(visual: TextureVisuals) -> Image.Image:
    image = getattr(visual.material, "image", None)
    if not isinstance(image, Image.Image):
        raise ValueError("the mesh's material has no texture image")
    return image


def paper_cylinder() -> SceneSpec:
    """The paper's 4.2 object: a single-colour cylinder (r 4 cm, h 12 cm), Rd = [230, 223, 205]/255,
    Rs = [27, 18, 28]/255, n = 59, under a distant (directional) light."""
    cyl = trimesh.creation.cylinder(radius=0.04, height=0.12, sections=256)
    # the side and the caps get their own vertices: shared rim vertices would average their normals and
    # round the sharp edges of the real object
    cap = np.abs(np.asarray(cyl.face_normals)[:, 2]) > 0.99
    parts = []
    for faces in (np.asarray(cyl.faces)[~cap], np.asarray(cyl.faces)[cap]):
        used, local = np.unique(faces, return_inverse=True)
        parts.append((np.asarray(cyl.vertices)[used], local.reshape(-1, 3)))
    vertices = np.concatenate([v for v, _ in parts])
    faces = np.concatenate([parts[0][1], parts[1][1] + len(parts[0][0])]).astype(np.int64)
    material = Material(tuple(np.array([230, 223, 205]) / 255), tuple(np.array([27, 18, 28]) / 255), 59.0)
    return SceneSpec(
        vertices,
        faces,
        np.zeros(len(faces), np.int64),
        [material],
        pose_matrix((0.0, 0.0, 0.06)),
        "directional",
        1.0,
    )


def lumpy_regions() -> SceneSpec:
    """A multi-region demo object: a lumpy body about 12 cm across in four materials — matte red, glossy
    green, sharp-highlight blue, and a broad-lobed cream top and bottom — lit by a point light. The
    simulator's own geometry (it shares no code with what it checks)."""
    body = trimesh.creation.icosphere(subdivisions=5)
    d = np.asarray(body.vertices)
    r = 1 + 0.07 * np.sin(3 * d[:, 0] + 0.5) * np.cos(2 * d[:, 1]) + 0.04 * d[:, 2] ** 2
    vertices = 0.06 * d * r[:, None] * np.array([1.0, 0.9, 0.8])
    faces = np.asarray(body.faces, np.int64)
    centre = d[faces].mean(axis=1)
    axis = np.argmax(np.abs(centre), axis=1)  # x → red, y → green (+y) / blue (−y), z → cream
    region = np.where(axis == 0, 0, np.where(axis == 2, 3, np.where(centre[:, 1] > 0, 1, 2)))
    materials = [
        Material((0.62, 0.18, 0.12), (0.05, 0.05, 0.05), 8.0),
        Material((0.15, 0.45, 0.18), (0.25, 0.25, 0.25), 60.0),
        Material((0.10, 0.16, 0.50), (0.40, 0.40, 0.40), 300.0),
        Material((0.80, 0.74, 0.60), (0.15, 0.15, 0.15), 20.0),
    ]
    lift = -vertices[:, 2].min()
    return SceneSpec(vertices, faces, region, materials, pose_matrix((0.0, 0.0, lift)), "point", 0.1)


BUILTIN_SCENES = {"cylinder": paper_cylinder, "lumpy": lumpy_regions}


def builtin_scene(name: str) -> SceneSpec:
    """A built-in scene by name (``builtin:cylinder`` or ``cylinder``)."""
    key = name.removeprefix("builtin:")
    if key not in BUILTIN_SCENES:
        raise SceneError(
            f"unknown built-in scene {name!r}; known: " + ", ".join(f"builtin:{k}" for k in BUILTIN_SCENES)
        )
    return BUILTIN_SCENES[key]()
