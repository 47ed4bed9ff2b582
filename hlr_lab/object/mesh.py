"""Meshes with surface colour: loading (OBJ, PLY, glTF), validation and derived geometry.

A :class:`ColouredMesh` is welded (one vertex per position), so adjacency and normals run across
UV seams; texture coordinates are kept per face corner. Colour is either per vertex (8-bit sRGB)
or a texture sampled at the corner UVs.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import trimesh
from PIL import Image
from trimesh.visual import ColorVisuals, TextureVisuals

from hlr_lab.errors import InputError
from hlr_lab.files import atomic_write_bytes, require_file
from hlr_lab.object.companions import refuse_special_companions

CREASE_DEG = 60.0  # faces meeting at a sharper angle than this do not share a shading normal

# trimesh gives an OBJ that has UVs but no material a 2×2 grey placeholder image; anything this
# small is not a real texture.
_PLACEHOLDER_TEXELS = 4
_FACE_BLOCK = 1 << 20


@dataclass(frozen=True, eq=False)
class ColouredMesh:
    """A triangle mesh in its own frame (metres) with surface colour.

    vertices       (V, 3) float64
    faces          (F, 3) int64, indices into ``vertices``
    vertex_colours (V, 3) uint8 sRGB, or None
    corner_uv      (F, 3, 2) float64 texture coordinates per face corner, or None
    texture        (H, W, 3) uint8 sRGB (row 0 is the top of the image), or None
    normals        (V, 3) float64 unit vertex normals given with the mesh (a planning proxy's: the mean
                   normal of the scan's vertices each of its vertices stands for), or None: computed
                   from the faces
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_colours: np.ndarray | None = None
    corner_uv: np.ndarray | None = None
    texture: np.ndarray | None = None
    source: Path | None = None
    sha256: str | None = None
    texture_source: Path | None = field(default=None)
    normals: np.ndarray | None = None

    @property
    def has_colour(self) -> bool:
        return self.vertex_colours is not None or (self.corner_uv is not None and self.texture is not None)

    @cached_property
    def trimesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)

    def _face_cross(self, faces: np.ndarray | slice) -> np.ndarray:
        """(N, 3) the cross products of the edges of the faces ``faces`` indexes: normal × twice the area."""
        v, f = self.vertices, self.faces[faces]
        corner = v[f[:, 0]]
        e1, e2 = v[f[:, 1]] - corner, v[f[:, 2]] - corner
        out = corner  # reused: a scan's blocks are the largest temporaries here
        for k in range(3):  # np.cross, without its general-shape overhead (~2× on millions)
            i, j = (k + 1) % 3, (k + 2) % 3
            out[:, k] = e1[:, i] * e2[:, j] - e1[:, j] * e2[:, i]
        return out

    def face_blocks(self) -> list[slice]:
        """The faces in blocks of ``_FACE_BLOCK``: a scan's per-face temporaries stay bounded (a whole
        (F, 3) float64 is 430 MB at 18 M faces, and a cross product makes four)."""
        n = len(self.faces)
        return [slice(start, min(start + _FACE_BLOCK, n)) for start in range(0, n, _FACE_BLOCK)]

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(F, 3) unit normals (counter-clockwise winding faces outward; 0 for a degenerate face). Not
        trimesh's, which keeps every face's corners (F × 72 bytes) and the cross product in its cache."""
        out = np.empty((len(self.faces), 3))
        for block in self.face_blocks():
            out[block] = self.face_normals_of(block)
        return out

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        """(V, 3) unit normals: those given with the mesh, else :meth:`area_weighted_normals` (kept)."""
        return self.normals if self.normals is not None else self.area_weighted_normals()

    def area_weighted_normals(self) -> np.ndarray:
        """(V, 3) unit normals, the area-weighted mean of the adjacent faces' normals, computed anew (a scan's
        planning proxy needs them once, and 240 MB at 10 M vertices need not stay)."""
        # the sum over each vertex's faces of their cross products (area-weighted normals): bincounts per
        # axis (np.add.at: 1.2–3× slower on millions), a block of faces at a time
        n = len(self.vertices)
        acc = np.zeros((n, 3))
        for block in self.face_blocks():
            cross = self._face_cross(block)
            corners = self.faces[block].ravel()  # (3B,) each face's three corners
            for k in range(3):
                acc[:, k] += np.bincount(corners, weights=np.repeat(cross[:, k], 3), minlength=n)
        norm = np.sqrt(np.einsum("ij,ij->i", acc, acc))[:, None]  # np.linalg.norm makes a (V, 3) temporary
        return np.divide(acc, norm, out=acc, where=norm > 0)  # in place: a vertex without area stays 0

    @cached_property
    def corner_normals(self) -> np.ndarray:
        """(F, 3, 3) the shading normal at each face corner: the area-weighted mean over the faces around
        the vertex that meet this face at less than ``CREASE_DEG``. Smooth across gentle bends, sharp
        across creases (a cylinder's rim, a box's edge), where one welded vertex normal would tilt the
        whole of the adjoining faces. Only vertices with a face more than half the crease angle off their
        smooth normal are worked out pair by pair; everywhere else this is ``vertex_normals``.
        """
        return self._worked_out_corner_normals(np.arange(len(self.faces)))

    def corner_normals_of(self, faces: np.ndarray) -> np.ndarray:
        """(N, 3, 3) :attr:`corner_normals` of the faces ``faces`` (N,) index.

        A G-buffer on a scan needs its hit faces', not all faces' (1.4 GB at 20 M faces): those are worked
        out alone, each distinct face once. Asked for at least as many as the mesh has faces (a G-buffer of
        a mesh coarser than the image: many pixels on each face), all of them are worked out and kept — no
        larger than the answer — and every later call indexes them. A crease vertex shared by many faces
        (a welded cylinder's cap centre: 128) makes a pair per face around it for every corner asked: per
        pixel, that was three quarters of a cylinder's colour turn (39 s, now 10 s).
        """
        if "corner_normals" in self.__dict__ or len(faces) >= len(self.faces):
            return self.corner_normals[faces]
        distinct, inverse = np.unique(faces, return_inverse=True)
        return self._worked_out_corner_normals(distinct)[inverse]

    def _worked_out_corner_normals(self, faces: np.ndarray) -> np.ndarray:
        """(N, 3, 3) :attr:`corner_normals` of the faces ``faces`` (N,) index, computed for them alone."""
        corners = self.faces[faces]  # (N, 3)
        out = self.vertex_normals[corners]
        corner_f, corner_c = np.nonzero(self._crease_vertices[corners])  # the corners to work out
        if len(corner_f) == 0:
            return out
        # pairs (corner, face around the corner's vertex) through the vertex → face incidence
        incidence = self._crease_incidence
        v = corners[corner_f, corner_c]
        counts = np.diff(incidence.indptr)[v]  # faces around each corner's vertex
        pair_corner = np.repeat(np.arange(len(v)), counts)
        rank = np.arange(len(pair_corner)) - np.repeat(
            np.cumsum(counts) - counts, counts
        )  # 0, 1, … per corner
        pair_face = incidence.indices[np.repeat(incidence.indptr[v], counts) + rank]
        own = self.face_normals_of(faces[corner_f])  # (C, 3) the corners' faces
        cross = self._face_cross(pair_face)
        double_area = np.linalg.norm(cross, axis=1)
        around = self.face_normals_of(pair_face)
        near = np.einsum("pk,pk->p", own[pair_corner], around) >= np.cos(np.radians(CREASE_DEG))
        weighted = around * (double_area * near)[:, None]
        acc = np.zeros((len(v), 3))
        np.add.at(acc, pair_corner, weighted)
        norm = np.linalg.norm(acc, axis=1, keepdims=True)
        out[corner_f, corner_c] = np.divide(acc, norm, out=own.copy(), where=norm > 0)
        return out

    def face_normals_of(self, faces: np.ndarray | slice) -> np.ndarray:
        """(N, 3) the unit normals of the faces ``faces`` indexes (0 for a degenerate face), worked out for them
        alone (:attr:`face_normals` keeps every face's: 480 MB on a 10 M-vertex scan). Asked for at least as
        many as the mesh has faces (the rays of an image on a coarse mesh), all are worked out once and kept:
        no larger than the answer."""
        if "face_normals" in self.__dict__ or (
            isinstance(faces, np.ndarray) and len(faces) >= len(self.faces)
        ):
            return self.face_normals[faces]
        cross = self._face_cross(faces)
        norm = np.linalg.norm(cross, axis=1, keepdims=True)
        return np.divide(cross, norm, out=np.zeros_like(cross), where=norm > 0)

    @cached_property
    def _crease_vertices(self) -> np.ndarray:
        """(V,) bool: the vertices with a face more than half ``CREASE_DEG`` off their smooth normal."""
        worst = np.ones(len(self.vertices))
        for block in self.face_blocks():
            cos_off = np.einsum(
                "fk,fck->fc", self.face_normals_of(block), self.vertex_normals[self.faces[block]]
            )
            np.minimum.at(worst, self.faces[block].ravel(), cos_off.ravel())
        return worst < np.cos(np.radians(CREASE_DEG / 2))

    @cached_property
    def _crease_incidence(self) -> sp.csr_matrix:
        """(V, F) boolean vertex → face incidence, its rows for the crease vertices alone (faces ascending)."""
        rows, cols = [], []
        for block in self.face_blocks():
            corners = self.faces[block].ravel()
            at_crease = np.flatnonzero(self._crease_vertices[corners])
            rows.append(corners[at_crease])
            cols.append(block.start + at_crease // 3)
        rows_, cols_ = np.concatenate(rows), np.concatenate(cols)
        return sp.csr_matrix(
            (np.ones(len(rows_), bool), (rows_, cols_)), shape=(len(self.vertices), len(self.faces))
        )

    @cached_property
    def face_areas(self) -> np.ndarray:
        """(F,) triangle areas, m²."""
        out = np.empty(len(self.faces))
        for block in self.face_blocks():
            out[block] = np.linalg.norm(self._face_cross(block), axis=1) / 2
        return out

    def surface_samples(self, count: int, seed: int) -> np.ndarray:
        """(count, 3) points spread evenly over the surface (each face drawn by its area, a point uniform in
        it), seeded: trimesh's ``sample_surface`` draws, without its copies of every face's corners (2 GB for
        a scan's 20 M faces)."""
        random = np.random.default_rng(seed).random
        cumulative = np.cumsum(self.face_areas)
        face = np.searchsorted(cumulative, random(count) * cumulative[-1])  # (count,)
        corners = self.vertices[self.faces[face]]  # (count, 3, 3)
        t = random((count, 2, 1))
        t[t.sum(axis=1)[:, 0] > 1.0] -= 1.0  # a point of the parallelogram's far half, folded into the face
        return corners[:, 0] + (np.abs(t) * (corners[:, 1:] - corners[:, :1])).sum(axis=1)

    @cached_property
    def vertex_areas(self) -> np.ndarray:
        """(V,) a third of the adjacent faces' area: the surface each vertex stands for."""
        out = np.zeros(len(self.vertices))
        for block in self.face_blocks():  # a scan's corner weights at once were 640 MB of temporaries
            corners = self.faces[block].ravel()  # (3B,)
            out += np.bincount(
                corners, weights=np.repeat(self.face_areas[block] / 3.0, 3), minlength=len(out)
            )
        return out

    def vertex_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """The mesh's edges, each once: their lower (E,) and higher (E,) vertex, int32, in that order,
        computed when asked (not kept). In int32 and one direction: a 10 M-vertex scan's 30 M edges take
        240 MB, where a symmetric int64 adjacency took gigabytes to build."""
        n = len(self.vertices)
        key = self._edge_keys()
        key.sort()  # an inner edge's two faces give it twice
        first = np.empty(len(key), dtype=bool)
        first[:1] = True
        np.not_equal(key[1:], key[:-1], out=first[1:])
        key = key[first]
        return (key // n).astype(np.int32), (key % n).astype(np.int32)

    def edge_faces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The faces on either side of each edge, computed when asked (not kept):

        shared (E, 2) int32, the lower and higher vertex of each edge two faces share, and faces (E, 2)
        int32, those two faces; rims (R, 2) int32, each edge of one face only (an open mesh's border), and
        rim_faces (R,) int32, that face. An edge of three or more faces (non-manifold) is in neither. The
        edges in order of their vertices."""
        f = len(self.faces)
        key = self._edge_keys()
        # face edge c·F + face, in the order of the edges' keys; the two faces of an edge in either order
        # (introsort: half a stable sort's time, 4 s of a 10 M-vertex scan's registration)
        order = np.argsort(key)
        # same[i]: sorted face edges i and i + 1 are one edge. Read in blocks, and the keys dropped after: a
        # sorted copy of a 10 M-vertex scan's 60 M keys would be another 480 MB at the peak
        same = np.zeros(len(key) + 1, dtype=bool)  # a False after the last, for the tests below
        for s in range(0, len(key) - 1, _FACE_BLOCK):
            k = key[order[s : s + _FACE_BLOCK + 1]]
            np.equal(k[1:], k[:-1], out=same[s : s + len(k) - 1])
        del key
        after = same[:-1]  # (3F,) the next is this edge
        before = np.zeros_like(after)  # (3F,) the previous is this edge
        before[1:] = same[: len(after) - 1]
        pair = np.flatnonzero(after & ~before & ~same[1:])  # exactly two faces: the next's next is another
        rim = np.flatnonzero(~after & ~before)  # one face
        del same, after, before

        def faces_at(at: np.ndarray) -> np.ndarray:
            out = np.empty(len(at), dtype=np.int32)
            for s in range(0, len(at), _FACE_BLOCK):
                out[s : s + _FACE_BLOCK] = order[at[s : s + _FACE_BLOCK]] % f
            return out

        def vertices(at: np.ndarray) -> np.ndarray:
            out = np.empty((len(at), 2), dtype=np.int32)
            for s in range(0, len(at), _FACE_BLOCK):
                # the edge c of face i (at c·F + i) joins the face's corners c and c + 1
                corner, face = np.divmod(order[at[s : s + _FACE_BLOCK]], f)
                a, b = self.faces[face, corner], self.faces[face, (corner + 1) % 3]
                out[s : s + _FACE_BLOCK, 0] = np.minimum(a, b)
                out[s : s + _FACE_BLOCK, 1] = np.maximum(a, b)
            return out

        faces = np.stack([faces_at(pair), faces_at(pair + 1)], axis=1)
        return vertices(pair), faces, vertices(rim), faces_at(rim)

    def _edge_keys(self) -> np.ndarray:
        """(3F,) int64: each face's edges as one key, lower·V + higher; edge c of face i at c·F + i."""
        n, f = len(self.vertices), len(self.faces)
        key = np.empty(3 * f, dtype=np.int64)
        for c in range(3):
            a, b = self.faces[:, c], self.faces[:, (c + 1) % 3]
            key[c * f : (c + 1) * f] = np.minimum(a, b) * n + np.maximum(a, b)
        return key

    def face_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Pairs of faces sharing an edge, each pair once: (E,) and (E,) face indices (not kept)."""
        faces = self.edge_faces()[1]
        return faces[:, 0], faces[:, 1]

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre (3,) and radius of the sphere about the bounding-box centre enclosing every vertex."""
        centre = 0.5 * (self.vertices.min(axis=0) + self.vertices.max(axis=0))
        return centre, float(np.linalg.norm(self.vertices - centre, axis=1).max())

    def transformed(self, matrix: np.ndarray) -> ColouredMesh:
        """The same mesh with a rigid/similarity 4×4 ``matrix`` applied to its vertices."""
        v = self.vertices @ matrix[:3, :3].T + matrix[:3, 3]
        faces = self.faces if np.linalg.det(matrix[:3, :3]) > 0 else self.faces[:, ::-1]
        uv = (
            None
            if self.corner_uv is None
            else (self.corner_uv if faces is self.faces else self.corner_uv[:, ::-1])
        )
        normals = None
        if self.normals is not None:  # a similarity turns normals as it turns the vertices (M⁻ᵀ ∝ M)
            normals = self.normals @ matrix[:3, :3].T
            normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        return ColouredMesh(
            v,
            faces,
            self.vertex_colours,
            uv,
            self.texture,
            self.source,
            self.sha256,
            self.texture_source,
            normals,
        )


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex), read in 1 MB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def texture_sha256(mesh: ColouredMesh) -> str | None:
    """The identity of ``mesh``'s texture as its regions are read from it: sha256 over the decoded pixels
    (H, W, 3 sRGB8) and their shape, however the image was found (``--texture``, an OBJ's .mtl, a glTF's
    image); None for a mesh without one. A texture repainted after planning changes the regions."""
    if mesh.texture is None:
        return None
    return arrays_sha256(np.array(mesh.texture.shape, np.int64), mesh.texture)


def arrays_sha256(*arrays: np.ndarray | None) -> str:
    """Identity of a mesh that has no file (built-in objects): sha256 over its arrays' bytes."""
    h = hashlib.sha256()
    for a in arrays:
        if a is not None:
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def load_mesh(
    path: str | Path, texture: str | Path | None = None, *, need_colour: bool = False
) -> ColouredMesh:
    """Read an OBJ, PLY or glTF/GLB mesh with vertex colours or a UV texture.

    ``texture`` supplies the image for an OBJ that has UVs but does not reference one.
    Raises :class:`InputError` naming the file for a missing/unreadable file, no faces, non-finite
    vertices, or (with ``need_colour``) no colour.
    """
    path = Path(path)
    require_file(path, "mesh")
    refuse_special_companions(path)  # trimesh would open them: a FIFO named by map_Kd blocks forever
    try:
        loaded = trimesh.load(path, process=False, force="mesh")
    except Exception as exc:  # trimesh raises many types for malformed files
        if path.suffix.lower() in (".obj", ".gltf"):  # a text format: trimesh guesses a non-UTF-8 file's
            _check_utf8(path)  # encoding with a package it may lack, and says only that
        if isinstance(exc, IndexError):  # trimesh's words for a face naming a vertex the file lacks
            raise InputError(
                f"a face refers to a vertex the file does not have ({exc}); repair the mesh", path=path
            ) from exc
        raise InputError(
            f"cannot read the mesh ({type(exc).__name__}: {exc}); give an OBJ, PLY, glTF or GLB file",
            path=path,
        ) from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise InputError(
            "the mesh has no faces; hlr-lab needs a triangle mesh (a point cloud will not do)", path=path
        )
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if not np.isfinite(vertices).all():
        bad = int((~np.isfinite(vertices)).any(axis=1).sum())
        raise InputError(f"{bad} vertices have NaN or infinite coordinates; repair the mesh", path=path)
    outside = (faces < 0) | (faces >= len(vertices))
    if outside.any():  # trimesh reads a PLY's faces as written, without checking them
        face, corner = np.argwhere(outside)[0]
        raise InputError(
            f"face {face} refers to vertex {faces[face, corner]}, but the file has {len(vertices)} "
            f"(0…{len(vertices) - 1}); repair the mesh",
            path=path,
        )

    vertex_colours, corner_uv, image = _colour_of(loaded, faces)
    texture_source = None
    if texture is not None:
        texture_source = Path(texture)
        image = _read_texture(texture_source)
        if corner_uv is None:
            raise InputError("a texture was given but the mesh has no texture coordinates (UVs)", path=path)
    if image is None:
        corner_uv = None

    first, inverse = _weld(vertices)
    vertices, faces = vertices[first], inverse[faces]
    if vertex_colours is not None:
        vertex_colours = vertex_colours[first]
    degenerate = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    faces, corner_uv = faces[~degenerate], None if corner_uv is None else corner_uv[~degenerate]
    if len(faces) == 0:
        raise InputError("every face of the mesh is degenerate (zero area)", path=path)
    mesh = ColouredMesh(
        vertices, faces, vertex_colours, corner_uv, image, path, file_sha256(path), texture_source
    )
    if need_colour and not mesh.has_colour:
        raise InputError(
            "the mesh has no colour (neither vertex colours nor a texture); give a coloured "
            "mesh or --texture PNG for an OBJ with UVs",
            path=path,
        )
    return mesh


def write_vertex_coloured_ply(path: str | Path, mesh: ColouredMesh) -> None:
    """Write ``mesh`` with its vertex colours as a binary PLY (in one piece: a crash leaves no half file)."""
    if mesh.vertex_colours is None:
        raise ValueError("the mesh has no vertex colours to write")
    rgba = np.hstack([mesh.vertex_colours[:, :3], np.full((len(mesh.vertices), 1), 255, np.uint8)])
    data = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=rgba, process=False).export(
        file_type="ply"
    )
    assert isinstance(data, bytes)  # PLY is binary by default
    atomic_write_bytes(path, data)


def _check_utf8(path: Path) -> None:
    """Refuse a text mesh file that is not UTF-8 text, saying where it stops being text (called once
    trimesh has failed on it: the good path reads the file once)."""
    try:
        path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"not a text {path.suffix[1:].upper()} file (byte {exc.object[exc.start]:#04x} at offset {exc.start} "
            "is not UTF-8 text): give an OBJ, PLY, glTF or GLB file",
            path=path,
        ) from exc


def _colour_of(loaded: trimesh.Trimesh, faces: np.ndarray):
    visual = loaded.visual
    kind = getattr(visual, "kind", None)
    if isinstance(visual, ColorVisuals) and kind == "vertex":
        return np.asarray(visual.vertex_colors)[:, :3].astype(np.uint8), None, None
    if isinstance(visual, ColorVisuals) and kind == "face":
        # per-face colour becomes per-vertex colour, the largest adjacent face winning a shared vertex
        fc = np.asarray(visual.face_colors)[:, :3].astype(np.uint8)
        vc = np.zeros((len(loaded.vertices), 3), np.uint8)
        order = np.argsort(np.asarray(loaded.area_faces))
        for corner in range(3):
            vc[faces[order, corner]] = fc[order]
        return vc, None, None
    if isinstance(visual, TextureVisuals) and visual.uv is not None:
        uv = np.asarray(visual.uv, dtype=np.float64)
        image = _material_image(visual.material)
        return None, uv[faces], image
    return None, None, None


def _material_image(material) -> np.ndarray | None:
    image = getattr(material, "image", None)
    if image is None:
        image = getattr(material, "baseColorTexture", None)
    if image is None:
        return None
    arr = np.asarray(image.convert("RGB"))
    if min(arr.shape[:2]) < _PLACEHOLDER_TEXELS:
        return None
    return arr


def _read_texture(path: Path) -> np.ndarray:
    require_file(path, "texture")
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except Exception as exc:
        raise InputError(f"cannot read the texture image ({exc}); give a PNG or JPEG", path=path) from exc


def _weld(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices at the same position (UV seams split them).

    Returns ``first`` (U,), the index of each kept vertex, and ``inverse`` (V,), old → new index.
    """
    scale = max(float(np.ptp(vertices, axis=0).max()), 1e-12)
    keys = np.round(vertices / (scale * 1e-9)).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    return first, inverse.ravel()


# barycentric sample points per face of a textured mesh: centroid plus six around it
FACE_SAMPLES = (
    np.array(
        [
            [1 / 3, 1 / 3, 1 / 3],
            [2 / 3, 1 / 6, 1 / 6],
            [1 / 6, 2 / 3, 1 / 6],
            [1 / 6, 1 / 6, 2 / 3],
            [1 / 2, 1 / 2, 0.0],
            [0.0, 1 / 2, 1 / 2],
            [1 / 2, 0.0, 1 / 2],
        ]
    )
    * 0.9
    + 0.1 / 3
)  # pulled 10 % toward the centroid so edge samples are not shared by two faces


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Nearest-texel lookup: ``uv`` (..., 2) in [0, 1] (v up, wrapped) → sRGB (..., 3) uint8."""
    h, w = texture.shape[:2]
    u = np.mod(uv[..., 0], 1.0)
    v = np.mod(uv[..., 1], 1.0)
    col = np.minimum((u * w).astype(np.int64), w - 1)
    row = np.minimum(((1.0 - v) * h).astype(np.int64), h - 1)
    return texture[row, col]
