"""The simulated camera: Mitsuba frames against eq. (1) evaluated independently, and the sensor model.

The independent side is hlr-lab's own geometry (Embree G-buffer, OpenCV camera model) — a different ray
engine and camera code from the renderer's.
"""

import numpy as np
import pytest
import scipy.ndimage as ndi
import trimesh

from hlr_lab.object.mesh import ColouredMesh
from hlr_lab.object.raycast import RayCaster
from sim.render.llvm import RendererUnavailable
from sim.render.sensor import SensorModel
from tests.cameras import half_size_camera
from tests.renderer_guard import require_renderer

require_renderer(module_level=True)
# after the guard: these import Mitsuba
from sim.render.camera import CameraSpec  # noqa: E402
from sim.render.renderer import Renderer  # noqa: E402
from sim.render.scene import Material, SceneSpec  # noqa: E402

RD, RS, N = np.array([0.55, 0.4, 0.3]), np.array([0.3, 0.3, 0.35]), 30.0


def scene_of(meshes: list[tuple[trimesh.Trimesh, Material]], power=1.0) -> SceneSpec:
    both = trimesh.util.concatenate([m for m, _ in meshes])
    region = np.concatenate([np.full(len(m.faces), i) for i, (m, _) in enumerate(meshes)])
    return SceneSpec(
        np.asarray(both.vertices),
        np.asarray(both.faces, np.int64),
        region,
        [m for _, m in meshes],
        np.eye(4),
        "point",
        power,
    )


def eq1(g, light, power, rd, rs, n, cam_centre):
    """Eq. (1) per pixel from a G-buffer: L = Φ/d², cos α = N·l, cos β = N·H."""
    x, normal = g.point, g.normal
    to_light = light - x
    d2 = np.einsum("...i,...i", to_light, to_light)
    unit_light = to_light / np.sqrt(d2)[..., None]
    v = cam_centre - x
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    h = (unit_light + v) / np.linalg.norm(unit_light + v, axis=-1, keepdims=True)
    cos_a = np.einsum("...i,...i", normal, unit_light)
    cos_b = np.clip(np.einsum("...i,...i", normal, h), 0, None)
    front = (cos_a > 0) & (np.einsum("...i,...i", normal, v) > 0)
    value = power / d2[..., None] * (rd * np.clip(cos_a, 0, None)[..., None] + rs * (cos_b**n)[..., None])
    return np.where(front[..., None], value, 0.0)


@pytest.mark.parametrize("aspect", [1.0, 1.05])
def test_sphere_frame_matches_eq1(aspect):
    """At fy = 1.05 fx the silhouette's top and bottom move ~4 px against a square-pixel render: past the
    3 px the comparison leaves out at the border, so a film that ignored the aspect would fail here."""
    cam = half_size_camera(aspect)
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=0.05)
    sphere.apply_translation([0.01, 0.0, 0.07])
    spec = scene_of([(sphere, Material(tuple(RD), tuple(RS), N))], power=0.2)
    renderer = Renderer(
        spec, CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480), spp=64
    )
    light = np.array([0.18, -0.25, 0.3])
    image = renderer.render(0.0, light)
    g = RayCaster(ColouredMesh(np.asarray(sphere.vertices), np.asarray(sphere.faces, np.int64))).gbuffer(cam)
    expected = eq1(g, light, 0.2, RD, RS, N, cam.centre)
    interior = ndi.binary_erosion(g.hit, iterations=3)  # silhouette pixels are partly background
    assert interior.sum() > 20_000
    err = image[interior] - expected[interior]
    psnr = 10 * np.log10(expected[interior].max() ** 2 / np.mean(err**2))
    assert psnr >= 50, f"PSNR {psnr:.1f} dB"
    assert np.abs(image[~ndi.binary_dilation(g.hit, iterations=3)]).max() == 0  # nothing outside the object


def test_shadows_fall_where_a_ray_test_says():
    cam = half_size_camera()
    plate = trimesh.creation.box(extents=[0.4, 0.4, 0.01])
    plate.apply_translation([0, 0, -0.005])
    block = trimesh.creation.box(extents=[0.04, 0.04, 0.04])
    block.apply_translation([0.0, 0.0, 0.09])
    grey = Material((0.6, 0.6, 0.6), (0.0, 0.0, 0.0), 10.0)
    renderer = Renderer(
        scene_of([(plate, grey), (block, grey)]),
        CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480),
        spp=16,
    )
    light = np.array([0.05, 0.02, 0.35])
    image = renderer.render(0.0, light).mean(axis=2)
    both = trimesh.util.concatenate([plate, block])
    caster = RayCaster(ColouredMesh(np.asarray(both.vertices), np.asarray(both.faces, np.int64)))
    g = caster.gbuffer(cam)
    on_plate = g.hit & (g.face < len(plate.faces)) & (np.abs(g.point[..., 2]) < 1e-6)
    pts, normals = g.point[on_plate], g.normal[on_plate]
    shadowed = caster.shadowed(pts, normals, light)
    assert 500 < shadowed.sum() < len(shadowed) - 500
    values = image[on_plate]
    shadow_img = np.zeros(on_plate.shape, bool)
    shadow_img[on_plate] = shadowed
    # pixels within 3 px of the shadow's border or the plate's edge are partly one thing and partly the other
    # (a pixel's area)
    border = ndi.binary_dilation(shadow_img, iterations=3) & ~ndi.binary_erosion(shadow_img, iterations=3)
    clear = (ndi.binary_erosion(on_plate, iterations=3) & ~border)[on_plate]
    assert np.all(values[shadowed & clear] == 0)
    assert np.all(values[~shadowed & clear] > 0)


def test_rerendering_moves_light_turntable_and_lamp():
    cam = half_size_camera()
    body = trimesh.creation.box(extents=[0.08, 0.04, 0.06])
    body.apply_translation([0.02, 0, 0.03])
    renderer = Renderer(
        scene_of([(body, Material((0.5, 0.5, 0.5), (0.2, 0.2, 0.2), 20.0))]),
        CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480),
        spp=4,
    )
    a = renderer.render(0.0, [0.2, -0.2, 0.3])
    b = renderer.render(0.0, [-0.2, -0.2, 0.3])
    c = renderer.render(45.0, [0.2, -0.2, 0.3])
    dark = renderer.render(45.0, [0.2, -0.2, 0.3], lamp_on=False)
    again = renderer.render(0.0, [0.2, -0.2, 0.3])
    assert not np.allclose(a, b)
    assert not np.allclose(a, c)
    assert dark.max() == 0
    np.testing.assert_allclose(again, a, atol=1e-6)  # same state, same seed: the same frame


def test_sensor_model_noise_and_clipping():
    sensor = SensorModel(bits=10, sensitivity=1000.0, electrons_per_dn=5.0, read_noise_dn=2.0)
    flat = np.full((200, 200, 3), 0.4)
    a = sensor.expose(flat, 0.5, np.random.default_rng(1))
    b = sensor.expose(flat, 0.5, np.random.default_rng(1))
    assert np.array_equal(a, b)
    assert a.dtype == np.uint16
    mean = 0.4 * 0.5 * 1000
    assert a.mean() == pytest.approx(mean, rel=0.01)
    expected_sd = np.sqrt(mean / 5.0 + 2.0**2 + 1 / 12)  # photon + read + quantisation
    assert a.std() == pytest.approx(expected_sd, rel=0.05)
    # photon and read noise as one normal draw (6 e of read noise here) or, with under 4 e, Poisson drawn
    # exactly: the same mean and variance at every level, the dark and the dim (a few electrons) included.
    # 120 000 values a level: the mean to ±0.02 DN and 0.04 % (over 3 standard errors), the variance to
    # ±2 % (5 standard errors: 0.4 %)
    for draw, e_per_dn in (("one normal", 3.0), ("Poisson", 1.5)):
        s = SensorModel(
            bits=12, sensitivity=1000.0, electrons_per_dn=e_per_dn, read_noise_dn=2.0, black_level_dn=64.0
        )
        for level in (0.0, 0.002, 0.02, 0.4, 3.0):  # 0, 1, 10, 200 and 1500 DN
            frame = s.expose(np.full((200, 200, 3), level), 0.5, np.random.default_rng(3)).astype(np.float64)
            mean = level * 0.5 * 1000
            assert frame.mean() - 64 == pytest.approx(mean, abs=0.02 + 4e-4 * mean), (draw, level)
            variance = mean / e_per_dn + 2.0**2 + 1 / 12
            assert frame.var() == pytest.approx(variance, rel=0.02), (draw, level)
    bright = sensor.expose(np.full((10, 10, 3), 10.0), 1.0, np.random.default_rng(2))
    assert bright.max() == 1023
    assert (bright == 1023).all()
    gamma = SensorModel(bits=8, sensitivity=255.0, electrons_per_dn=None, read_noise_dn=0.0, response="gamma")
    assert gamma.expose(np.full((1, 1, 3), 0.25), 1.0, np.random.default_rng(0))[0, 0, 0] == round(
        255 * 0.25 ** (1 / 2.2)
    )


def test_scene_file_assigns_faces_to_the_nearest_listed_colour(tmp_path):
    from sim.render.scene import SceneError, load_scene

    box = trimesh.creation.box(extents=[0.1, 0.1, 0.1])
    colours = np.where(box.vertices[:, 2:3] > 0, [[200, 40, 30]], [[30, 60, 200]]).astype(np.uint8)
    trimesh.Trimesh(box.vertices, box.faces, vertex_colors=colours, process=False).export(
        tmp_path / "box.ply"
    )
    (tmp_path / "scene.toml").write_text(
        '[object]\nmesh = "box.ply"\nplaced = { translation_m = [0, 0, 0.05], rotation_deg = [0, 0, 90] }\n'
        "[[region]]\ncolor = [205, 40, 35]\nrd = [0.6, 0.1, 0.1]\nrs = [0.2, 0.2, 0.2]\nn = 50\n"
        "[[region]]\ncolor = [25, 60, 210]\nrd = [0.1, 0.2, 0.6]\nrs = [0.1, 0.1, 0.1]\nn = 10\n"
        '[light]\ntype = "point"\npower = 2.0\n'
    )
    spec = load_scene(tmp_path / "scene.toml")
    top = box.vertices[box.faces][:, :, 2].mean(axis=1) > 0.049  # faces of the top side (+z): all corners red
    bottom = box.vertices[box.faces][:, :, 2].mean(axis=1) < -0.049
    assert (spec.face_region[top] == 0).all()
    assert (spec.face_region[bottom] == 1).all()
    assert spec.materials[0].n == 50
    assert spec.power == 2.0
    np.testing.assert_allclose(spec.mesh_to_turntable[:3, 3], [0, 0, 0.05])
    np.testing.assert_allclose(spec.mesh_to_turntable[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # a material no surface can have is refused, naming the region (the simulator once rendered n = −3)
    text = (tmp_path / "scene.toml").read_text()
    for bad, said in (("n = 50", "n = -3"), ("rd = [0.6, 0.1, 0.1]", "rd = [2.0, 0.1, 0.1]"),
                      ("n = 50", "n = nan")):  # fmt: skip
        (tmp_path / "bad.toml").write_text(text.replace(bad, said))
        with pytest.raises(SceneError, match=r"region\[0\]"):
            load_scene(tmp_path / "bad.toml")
    # a misspelt key would leave its default in place unseen; a lamp of power 0 lights nothing
    for bad, said, where in (("n = 50", "n = 50\nrss = [0.5, 0.5, 0.5]", r"region\[0\]\.rss: not a key"),
                             ("power = 2.0", "power = 2.0\npowr = 3", r"light\.powr: not a key"),
                             ("rotation_deg", "rotation", r"object\.placed\.rotation: not a key"),
                             ("placed = {", "pose = {", r"object\.pose: no longer read.*object\.placed"),
                             ("power = 2.0", "power = 0", r"light\.power")):  # fmt: skip
        (tmp_path / "bad.toml").write_text(text.replace(bad, said))
        with pytest.raises(SceneError, match=where):
            load_scene(tmp_path / "bad.toml")


def test_paper_cylinder_under_a_directional_light():
    from sim.render.scene import paper_cylinder

    cam = half_size_camera()
    renderer = Renderer(
        paper_cylinder(),
        CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480),
        spp=4,
    )
    lit = renderer.render(0.0, [-0.3, 1.0, -0.2])  # the light travels toward +y, from the camera's side
    assert lit.max() > 0.5
    # a white-ish diffuse surface under irradiance Φ = 1 reads about Rd·cos α: never above Rd + Rs
    assert lit.max() <= (230 + 27) / 255 + 1e-3
    # lit from behind, the camera sees the dark side, but for the sliver its perspective shows past 90°
    assert renderer.render(0.0, [0.0, -1.0, 0.0]).max() < 0.1 * lit.max()


def test_path_tracing_adds_inter_reflection_in_a_corner():
    cam = half_size_camera()
    floor = trimesh.creation.box(extents=[0.2, 0.2, 0.01])
    floor.apply_translation([0, 0.05, -0.005])
    wall = trimesh.creation.box(extents=[0.2, 0.01, 0.15])
    wall.apply_translation([0, 0.1, 0.075])
    white = Material((0.8, 0.8, 0.8), (0.0, 0.0, 0.0), 10.0)
    spec = scene_of([(floor, white), (wall, white)])
    camera = CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480)
    light = [0.0, -0.1, 0.25]
    direct = Renderer(spec, camera, spp=64).render(0.0, light)
    path = Renderer(spec, camera, spp=64, integrator="path", max_depth=3).render(0.0, light)
    lit = direct.mean(axis=2) > 0
    gain = path.mean(axis=2)[lit].mean() / direct.mean(axis=2)[lit].mean()
    assert 1.03 < gain < 2.0  # the wall lights the floor and back: more light, not a different picture


def test_textured_scene_file(tmp_path):
    from PIL import Image

    from sim.render.scene import load_scene

    (tmp_path / "quad.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0.1 0.5\nvt 0.2 0.5\nvt 0.8 0.5\nvt 0.9 0.5\n"
        "f 1/1 2/2 4/1\nf 2/4 3/3 4/4\n"
    )
    tex = np.zeros((4, 4, 3), np.uint8)
    tex[:, :2] = [250, 10, 10]
    tex[:, 2:] = [10, 10, 250]
    Image.fromarray(tex).save(tmp_path / "tex.png")
    (tmp_path / "scene.toml").write_text(
        '[object]\nmesh = "quad.obj"\ntexture = "tex.png"\n'
        "[[region]]\ncolor = [255, 0, 0]\nrd = [0.5, 0.1, 0.1]\nrs = [0, 0, 0]\nn = 1\n"
        "[[region]]\ncolor = [0, 0, 255]\nrd = [0.1, 0.1, 0.5]\nrs = [0, 0, 0]\nn = 1\n"
    )
    spec = load_scene(tmp_path / "scene.toml")
    assert spec.face_region.tolist() == [0, 1]  # each face takes the texel colour at its UV centroid


def test_missing_libllvm_says_what_to_install(monkeypatch, tmp_path):
    import sim.render.llvm as llvm

    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    (tmp_path / "libLLVM-15.so.1").touch()  # too old: LLVM 15 cannot compile Mitsuba 3.9's kernels
    monkeypatch.setattr(llvm, "_SEARCH", (str(tmp_path),))
    with pytest.raises(RendererUnavailable, match="apt-get install libllvm19"):
        llvm.find_libllvm()
    (tmp_path / "libLLVM.so.19.1").touch()
    assert llvm.find_libllvm().endswith("libLLVM.so.19.1")


def test_builtin_multi_region_scene_renders_each_material():
    from sim.render.scene import builtin_scene

    spec = builtin_scene("builtin:lumpy")
    assert sorted(set(spec.face_region.tolist())) == [0, 1, 2, 3]
    assert spec.vertices[:, 2].min() + spec.mesh_to_turntable[2, 3] == pytest.approx(
        0.0
    )  # resting on the plate
    cam = half_size_camera()
    renderer = Renderer(
        spec, CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480), spp=4
    )
    image = renderer.render(0.0, [0.1, -0.25, 0.3])
    assert image.max() > 0
    with pytest.raises(Exception, match="unknown built-in scene"):
        builtin_scene("builtin:teapot")


def test_rendering_only_the_objects_box_changes_nothing():
    cam = half_size_camera()
    body = trimesh.creation.icosphere(subdivisions=4, radius=0.05)
    body.apply_translation([0.03, 0.0, 0.06])
    renderer = Renderer(
        scene_of([(body, Material((0.5, 0.4, 0.3), (0.3, 0.3, 0.3), 30.0))]),
        CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480),
        spp=16,
    )
    cropped = renderer.render(20.0, [0.2, -0.2, 0.3])
    x, y, w, h = renderer._crop
    assert w * h < 0.5 * renderer.film.width * renderer.film.height  # the crop really is smaller
    mi, p = renderer.mi, renderer._params
    renderer._crop = (0, 0, renderer.film.width, renderer.film.height)
    p["sensor.film.crop_offset"] = mi.ScalarPoint2u(0, 0)
    p["sensor.film.crop_size"] = mi.ScalarVector2u(renderer.film.width, renderer.film.height)
    full = renderer.render(20.0, [0.2, -0.2, 0.3])
    assert cropped.max() > 0
    # every pixel the full render lights lies inside the crop (projected through the distortion)
    inside = np.zeros(full.shape[:2], bool)
    inside[y : y + h, x : x + w] = True
    assert not ((full.max(axis=2) > 0) & ~inside).any()
    # pixel jitter is seeded per pixel of the rendered block: values agree up to Monte-Carlo noise, which
    # matters only on silhouette pixels (partly hit, partly missed)
    assert np.abs(cropped - full).mean() < 1e-3 * full.max()
    interior = ndi.binary_erosion(full.max(axis=2) > 0, iterations=2)
    # at 16 spp a pixel on the specular peak moves by a few per cent of the peak with its jitter
    np.testing.assert_allclose(cropped[interior], full[interior], atol=0.05 * full.max())


def test_textured_regions_follow_texels_across_faces(tmp_path):
    from PIL import Image

    from sim.render.scene import load_scene

    # a 10 cm quad facing the camera (−y), two triangles; the texture's colour border at u = 0.5 crosses both
    (tmp_path / "quad.obj").write_text(
        "v -0.05 0 0.02\nv 0.05 0 0.02\nv 0.05 0 0.12\nv -0.05 0 0.12\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
    )
    tex = np.zeros((8, 8, 3), np.uint8)
    tex[:, :4] = [250, 10, 10]
    tex[:, 4:] = [10, 10, 250]
    Image.fromarray(tex).save(tmp_path / "tex.png")
    (tmp_path / "scene.toml").write_text(
        '[object]\nmesh = "quad.obj"\ntexture = "tex.png"\n'
        "[[region]]\ncolor = [255, 0, 0]\nrd = [0.8, 0.1, 0.1]\nrs = [0, 0, 0]\nn = 1\n"
        "[[region]]\ncolor = [0, 0, 255]\nrd = [0.1, 0.1, 0.8]\nrs = [0, 0, 0]\nn = 1\n"
    )
    spec = load_scene(tmp_path / "scene.toml")
    assert spec.region_texture is not None
    cam = half_size_camera()
    image = Renderer(
        spec, CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480), spp=4
    ).render(0.0, cam.centre)
    pixels, _ = cam.project(
        np.array([[-0.025, 0.0, 0.05], [0.025, 0.0, 0.05], [-0.025, 0, 0.1], [0.025, 0, 0.1]])
    )
    for (u, v), red in zip(np.round(pixels).astype(int), (True, False, True, False), strict=True):
        r, _, b = image[v, u]
        assert (r > 4 * b) if red else (b > 4 * r), (u, v, image[v, u])


@pytest.mark.parametrize("aspect", [1.0, 1.05])
def test_the_sensor_casts_the_camera_models_rays(aspect):
    """The sensor renders on the camera's own pixel grid: the ray it casts for a point of the film is the
    OpenCV model's ray through that point (hlr-lab's Camera, cv2.undistortPoints), at the corners and
    with a crop window — so a pixel is the box mean over its own square, nothing resampled. Measured:
    within 5e-8 rad (float32 directions)."""
    from sim.render.camera import CameraFilm
    from sim.render.llvm import load_mitsuba

    mi = load_mitsuba()
    from sim.render import opencv_sensor  # a Mitsuba class: once the variant is set

    opencv_sensor.register()
    cam = half_size_camera(aspect)
    film = CameraFilm(CameraSpec(cam.matrix, cam.distortion, cam.rotation, cam.translation, 640, 480))
    sensor = mi.load_dict(film.sensor_dict(1))
    params = mi.traverse(sensor)
    offset, size = (100, 40), (300, 200)
    params["film.crop_offset"] = mi.ScalarPoint2u(*offset)
    params["film.crop_size"] = mi.ScalarVector2u(*size)
    params.update()
    rng = np.random.default_rng(0)
    position = np.vstack([rng.uniform(0, 1, (200, 2)), [[0, 0], [1, 1], [0, 1], [1, 0]]])
    ray, weight = sensor.sample_ray(
        0.0, 0.5, mi.Point2f(position[:, 0], position[:, 1]), mi.Point2f(0.5, 0.5)
    )
    direction = np.array(ray.d, np.float64).T
    origin = np.broadcast_to(np.array(ray.o).T, direction.shape)  # one centre for every ray
    pixels = np.asarray(offset) + position * np.asarray(size) - 0.5  # Mitsuba's pixel i spans [i, i + 1)
    origins, expected = cam.pixel_rays(pixels)
    expected = expected / np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(origin, origins, atol=1e-6)
    angle = np.linalg.norm(np.cross(direction, expected), axis=1)  # sin θ: arccos of a float32 dot is ±3e-4
    assert angle.max() < 1e-6, f"{angle.max():.2e} rad"
    np.testing.assert_allclose(np.array(weight), 1.0)
    assert (film.width, film.height) == (640, 480)
