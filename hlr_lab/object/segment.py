"""Colour regions (paper §3.1): parts of the surface with the same colour share one reflectance.

Pipeline, each step a pure function:
1. colour samples on a graph: vertex colours on the vertex graph, or texture samples on the face graph;
2. cluster the sample colours in CIELAB into materials: the count comes from a ΔE threshold (or is given);
3. merge tiny connected fragments (anti-aliased borders, speckles) into the neighbour they share most edges with;
4. regions = materials, or (``split_connected``) each connected patch of a material;
5. per-vertex and per-face labels plus a summary.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hlr_lab.errors import InputError
from hlr_lab.files import as_triple
from hlr_lab.geometry.colour import linear_to_srgb8, srgb8_to_lab, srgb8_to_linear
from hlr_lab.object.grouping import connected_groups, group_rows
from hlr_lab.object.mesh import FACE_SAMPLES, ColouredMesh, sample_texture

DEFAULT_DELTA_E = 10.0
DEFAULT_MIN_FRAGMENT = 0.001  # fraction of the total surface area
_LAB_BIN = 0.5  # ΔE; colours closer than this are one bin before clustering (speed only)
_KMEANS_ITERATIONS = 20
_EDGE_BLOCK = 1 << 20  # edges whose two labels are compared at a time
_FACE_BLOCK = 1 << 20  # faces' labels a block at a time: a scan's (F, 3) labels and weights are ~1 GB


@dataclass(frozen=True)
class Region:
    """One same-colour region: its id, material cluster, mean colour, size (vertices, faces, m²)."""

    id: int
    material: int
    colour: tuple[int, int, int]  # mean surface colour, 8-bit sRGB
    vertices: int
    faces: int
    area_m2: float


@dataclass(frozen=True, eq=False)
class Segmentation:
    """vertex_labels (V,) and face_labels (F,) hold region ids; ``regions`` is sorted by id."""

    vertex_labels: np.ndarray
    face_labels: np.ndarray
    regions: list[Region]
    delta_e: float
    split_connected: bool
    min_fragment: float

    @property
    def n_regions(self) -> int:
        return len(self.regions)


def segment(
    mesh: ColouredMesh,
    *,
    delta_e: float = DEFAULT_DELTA_E,
    n_materials: int | None = None,
    split_connected: bool = False,
    min_fragment: float = DEFAULT_MIN_FRAGMENT,
) -> Segmentation:
    """Split the surface of ``mesh`` into same-colour regions (ids ordered by area, largest first)."""
    if not mesh.has_colour:
        raise InputError(
            "the mesh has no colour to segment; give vertex colours or --texture PNG", path=mesh.source
        )
    if n_materials is not None and n_materials < 1:
        raise InputError(f"--regions must be at least 1, got {n_materials}", field="--regions")
    vertex_colours = mesh.vertex_colours
    on_faces = vertex_colours is None
    if vertex_colours is None:
        texture, corner_uv = mesh.texture, mesh.corner_uv
        assert texture is not None  # has_colour: without vertex colours, a texture and its UVs
        assert corner_uv is not None
        srgb = sample_texture(texture, np.einsum("sk,fkt->fst", FACE_SAMPLES, corner_uv))
        samples = srgb.reshape(-1, 3)
        sample_weight = np.repeat(mesh.face_areas / len(FACE_SAMPLES), len(FACE_SAMPLES))
        node_weight, edges = mesh.face_areas, mesh.face_edges()
    else:
        samples, sample_weight = vertex_colours, mesh.vertex_areas
        node_weight, edges = mesh.vertex_areas, mesh.vertex_edges()

    # the distinct colours clustered, each weighted by its samples: a scan's millions of samples hold
    # few colours, and Lab for each sample took (N, 3) float64 temporaries over and over
    colour_of, first = group_rows([samples[:, c] for c in range(3)])
    sample_label = cluster_colours(
        srgb8_to_lab(samples[first]),
        np.bincount(colour_of, weights=sample_weight, minlength=len(first)),
        delta_e=delta_e,
        n_clusters=n_materials,
    )[colour_of]
    del colour_of
    if on_faces:
        node_label = weighted_mode(
            sample_label.reshape(len(mesh.faces), -1),
            np.broadcast_to(sample_weight.reshape(len(mesh.faces), -1), (len(mesh.faces), len(FACE_SAMPLES))),
        )
    else:
        node_label = sample_label
    if n_materials is None:  # with a fixed count, every requested material stays
        node_label = merge_fragments(node_label, edges, node_weight, min_fragment * node_weight.sum())
    node_material = node_label
    if split_connected:
        node_label = _components(node_label, edges)
    del edges  # a scan's edges: 240 MB not needed from here on

    if on_faces:
        face_labels = node_label
        vertex_labels = _vertex_majority(mesh, face_labels)
    else:
        vertex_labels = node_label
        face_labels = _face_modes(mesh, vertex_labels)

    material = _material_of(node_label, node_material)
    per_node = len(samples) // len(node_label)
    sample_region = np.repeat(node_label, per_node)
    # a region's colour is that of its material's samples: anti-aliased borders and the odd texel of
    # another colour inside it (an eye's glint) would otherwise pull the mean toward other regions
    own = sample_label == np.repeat(node_material, per_node)
    return _summarise(
        mesh,
        vertex_labels,
        face_labels,
        node_label,
        material,
        sample_region[own],
        samples[own],
        sample_weight[own],
        delta_e,
        split_connected,
        min_fragment,
    )


def cluster_colours(
    lab: np.ndarray, weight: np.ndarray, *, delta_e: float, n_clusters: int | None = None
) -> np.ndarray:
    """Cluster (N, 3) Lab colours with (N,) weights; returns (N,) cluster ids 0…K−1.

    Automatic K: seed a centre at the heaviest colour not within ``delta_e`` of a centre, refine by
    weighted k-means, then merge centres closer than ``delta_e``. Given K: weighted farthest-point
    seeding then k-means. Deterministic.
    """
    inverse, first = group_rows(np.round(lab / _LAB_BIN).astype(np.int64))  # the bins in np.unique's order
    bin_lab = np.column_stack(
        [np.bincount(inverse, weights=lab[:, c] * weight, minlength=len(first)) for c in range(3)]
    )
    bin_w = np.bincount(inverse, weights=weight, minlength=len(first))
    bin_lab = np.where(bin_w[:, None] > 0, bin_lab / np.maximum(bin_w, 1e-300)[:, None], lab[first])
    bin_w = np.maximum(bin_w, 1e-300)  # zero-area samples still get a label

    if n_clusters is None:
        centres = _leader_seeds(bin_lab, bin_w, delta_e)
    else:
        if n_clusters > len(bin_lab):
            raise InputError(
                f"--regions {n_clusters} asks for more regions than the mesh has distinct "
                f"colours ({len(bin_lab)})",
                field="--regions",
            )
        centres = _farthest_seeds(bin_lab, bin_w, n_clusters)
    label, centres = _kmeans(bin_lab, bin_w, centres)
    if n_clusters is None:
        label = _merge_close(bin_lab, bin_w, label, centres, delta_e)
    return _compact(label)[inverse]


def _leader_seeds(lab: np.ndarray, w: np.ndarray, delta_e: float) -> np.ndarray:
    order = np.argsort(-w, kind="stable")
    lab = lab[order]
    free = np.ones(len(lab), bool)
    seeds = []
    while free.any():
        i = int(np.argmax(free))  # heaviest colour not yet near a centre
        seeds.append(lab[i])
        free &= np.linalg.norm(lab - lab[i], axis=1) > delta_e
    return np.array(seeds)


def _farthest_seeds(lab: np.ndarray, w: np.ndarray, k: int) -> np.ndarray:
    seeds = [int(np.argmax(w))]
    d2 = np.sum((lab - lab[seeds[0]]) ** 2, axis=1)
    for _ in range(k - 1):
        seeds.append(int(np.argmax(w * d2)))
        d2 = np.minimum(d2, np.sum((lab - lab[seeds[-1]]) ** 2, axis=1))
    return lab[seeds]


def _kmeans(lab: np.ndarray, w: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    label = np.zeros(len(lab), np.int64)
    for _ in range(_KMEANS_ITERATIONS):
        d2 = ((lab[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
        new = np.argmin(d2, axis=1)
        sums = np.zeros_like(centres)
        np.add.at(sums, new, lab * w[:, None])
        mass = np.bincount(new, weights=w, minlength=len(centres))
        centres = np.where(mass[:, None] > 0, sums / np.maximum(mass, 1e-300)[:, None], centres)
        if np.array_equal(new, label):
            break
        label = new
    return label, centres


def _merge_close(lab, w, label, centres, delta_e) -> np.ndarray:
    """Merge clusters whose weighted centres are within ``delta_e`` (closest pair first)."""
    while True:
        ids = np.unique(label)
        if len(ids) < 2:
            return label
        mass = np.bincount(label, weights=w)[ids]
        c = np.stack([np.average(lab[label == i], axis=0, weights=w[label == i]) for i in ids])
        d = np.linalg.norm(c[:, None] - c[None], axis=2)
        np.fill_diagonal(d, np.inf)
        a, b = np.unravel_index(np.argmin(d), d.shape)
        if d[a, b] > delta_e:
            return label
        keep, drop = (ids[a], ids[b]) if mass[a] >= mass[b] else (ids[b], ids[a])
        label = np.where(label == drop, keep, label)


def _compact(label: np.ndarray) -> np.ndarray:
    return np.unique(label, return_inverse=True)[1].ravel()


def weighted_mode(labels: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Row-wise weighted mode of (N, k) integer labels with (N, k) weights → (N,) (ties: the smaller
    label). For the few columns of a face's corners or samples: each column's total is summed over the
    k columns that carry its label (k² passes over N rows; the general :func:`heaviest_label` sorts the
    N·k votes, ~5× slower on millions of faces)."""
    labels = np.asarray(labels, dtype=np.int64)
    weights = np.broadcast_to(np.asarray(weights, dtype=np.float64), labels.shape)
    k = labels.shape[1]
    # the same columns in the same order for every column of one label: equal labels get equal totals
    total = np.stack(
        [sum(np.where(labels[:, j] == labels[:, i], weights[:, j], 0.0) for j in range(k)) for i in range(k)],
        axis=1,
    )  # (N, k)
    best = total.max(axis=1, keepdims=True)
    return np.where(total >= best, labels, np.iinfo(np.int64).max).min(axis=1)


def heaviest_label(rows: np.ndarray, labels: np.ndarray, weights: np.ndarray, n_rows: int) -> np.ndarray:
    """For votes (row, label, weight): per row, the label with the largest summed weight (ties: the
    smaller label); −1 for rows without a vote. Vectorised (scipy's sparse argmax loops in Python)."""
    n_labels = int(labels.max()) + 1 if len(labels) else 1
    code, inv = np.unique(rows.astype(np.int64) * n_labels + labels, return_inverse=True)
    total = np.bincount(inv.ravel(), weights=weights)
    r, c = code // n_labels, code % n_labels
    order = np.lexsort((c, -total, r))
    first = order[np.r_[True, r[order][1:] != r[order][:-1]]]
    out = np.full(n_rows, -1, dtype=np.int64)
    out[r[first]] = c[first]
    return out


def merge_fragments(
    label: np.ndarray, edges: tuple[np.ndarray, np.ndarray], weight: np.ndarray, min_weight: float
) -> np.ndarray:
    """Relabel connected same-label patches lighter than ``min_weight`` to the neighbouring label they
    share most edges with; repeats until none is left (a patch with no neighbour stays). ``label`` (N,)
    and ``weight`` (N,) per node, ``edges`` the node pairs (E,) and (E,) joined, each pair once."""
    label = label.copy()
    u, v = edges
    for _ in range(50):
        same = _same_label(label, edges)  # (E,): the few others are the borders between patches
        comp = _components(label, edges, same)
        comp_w = np.bincount(comp, weights=weight)
        small = comp_w < min_weight
        border = (u[~same], v[~same])
        del same
        # every border edge from a small patch into a patch that is not small, in either direction
        row, col = _crossing(border, comp, small, ~small)
        if len(row) == 0:
            # small patches bordering only small patches: let the lightest join its neighbour
            lightest = np.arange(len(comp_w)) == np.argmin(np.where(small, comp_w, np.inf))
            row, col = _crossing(border, comp, small & lightest, np.ones(len(comp_w), bool))
            if len(row) == 0:
                return label
        new_label_of_comp = heaviest_label(comp[row], label[col], np.ones(len(row)), comp.max() + 1)
        moved = new_label_of_comp[comp]
        label = np.where(moved >= 0, moved, label)
    return label


def _crossing(
    border: tuple[np.ndarray, np.ndarray], comp: np.ndarray, source: np.ndarray, target: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Border edges (between two labels, each stored once) taken in both directions: those (from, to)
    whose ``from`` lies in a patch of ``comp`` that ``source`` (per patch, bool) selects and ``to`` in one
    that ``target`` selects."""
    u, v = border
    forward = source[comp[u]] & target[comp[v]]
    backward = source[comp[v]] & target[comp[u]]
    return np.concatenate([u[forward], v[backward]]), np.concatenate([v[forward], u[backward]])


def _same_label(label: np.ndarray, edges: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(E,) bool: the edges' two nodes carry one label; a block of edges at a time (a scan's labels of
    both ends at once were 2 × 240 MB of int64)."""
    u, v = edges
    same = np.empty(len(u), bool)
    for start in range(0, len(u), _EDGE_BLOCK):
        block = slice(start, start + _EDGE_BLOCK)
        np.equal(label[u[block]], label[v[block]], out=same[block])
    return same


def _components(
    label: np.ndarray, edges: tuple[np.ndarray, np.ndarray], same: np.ndarray | None = None
) -> np.ndarray:
    """(N,) the connected same-label patch of each node (numbered from the lowest node up); ``same`` (E,)
    whether each edge joins two nodes of one label, when already known."""
    u, v = edges
    joined = _same_label(label, edges) if same is None else same
    return connected_groups(len(label), u, v, where=joined)


def _face_modes(mesh: ColouredMesh, vertex_labels: np.ndarray) -> np.ndarray:
    """(F,) each face's label: its corners' label weighted by their vertex areas (:func:`weighted_mode`), a
    million faces at a time (a scan's (F, 3) labels and weights at once are ~1 GB)."""
    out = np.empty(len(mesh.faces), dtype=vertex_labels.dtype)
    for start in range(0, len(mesh.faces), _FACE_BLOCK):
        corners = mesh.faces[start : start + _FACE_BLOCK]
        out[start : start + len(corners)] = weighted_mode(vertex_labels[corners], mesh.vertex_areas[corners])
    return out


def _vertex_majority(mesh: ColouredMesh, face_labels: np.ndarray) -> np.ndarray:
    """Each vertex takes the label covering most of its adjacent area."""
    return heaviest_label(
        mesh.faces.ravel(), np.repeat(face_labels, 3), np.repeat(mesh.face_areas, 3), len(mesh.vertices)
    )


def _material_of(node_label: np.ndarray, colour_label: np.ndarray) -> np.ndarray:
    """Material (colour cluster) of each node label: the colour cluster most of its nodes carry."""
    return heaviest_label(node_label, colour_label, np.ones(len(node_label)), int(node_label.max()) + 1)


def _summarise(
    mesh,
    vertex_labels,
    face_labels,
    node_label,
    material,
    sample_region,
    sample_srgb8,
    sample_weight,
    delta_e,
    split_connected,
    min_fragment,
) -> Segmentation:
    # the labels in use, ascending (np.unique of both concatenated: a scan's 30 M labels copied and sorted)
    size = int(max(vertex_labels.max(initial=-1), face_labels.max(initial=-1))) + 1
    used = np.flatnonzero(
        (np.bincount(vertex_labels, minlength=size) > 0) | (np.bincount(face_labels, minlength=size) > 0)
    )
    area = np.bincount(face_labels, weights=mesh.face_areas, minlength=used.max() + 1)
    order = used[np.lexsort((used, -area[used]))]  # largest area first, ties by old id
    new_id = np.full(used.max() + 1, -1, dtype=np.int32)  # int32: a scan's labels at half the memory
    new_id[order] = np.arange(len(order))
    vertex_labels, face_labels = new_id[vertex_labels], new_id[face_labels]
    sample_new = new_id[sample_region]

    # per channel through a table of the 256 levels: a scan's (V, 3) float64 conversion took 1.2 GB at once
    linear = srgb8_to_linear(np.arange(256))
    colour_sum = np.column_stack(
        [
            np.bincount(sample_new, weights=linear[sample_srgb8[:, k]] * sample_weight, minlength=len(order))
            for k in range(3)
        ]
    )
    mass = np.bincount(sample_new, weights=sample_weight, minlength=len(order))
    mean_colour = linear_to_srgb8(colour_sum / np.maximum(mass, 1e-300)[:, None])
    n_vert = np.bincount(vertex_labels, minlength=len(order))
    n_face = np.bincount(face_labels, minlength=len(order))
    area_new = np.bincount(face_labels, weights=mesh.face_areas, minlength=len(order))
    material_new = _compact(material[order])
    regions = [
        Region(
            int(i),
            int(material_new[i]),
            as_triple([int(c) for c in mean_colour[i]]),
            int(n_vert[i]),
            int(n_face[i]),
            float(area_new[i]),
        )
        for i in range(len(order))
    ]
    return Segmentation(vertex_labels, face_labels, regions, delta_e, split_connected, min_fragment)
