"""A MuJoCo model's geoms as triangle meshes, and their poses over a replay (pure numpy/MuJoCo).

Each drawn geom becomes one mesh in its own frame (`geom_shapes`): boxes, spheres, capsules,
cylinders, ellipsoids and meshes; planes, height fields and SDFs are left out (the viewer draws
its own floor). `geom_poses` runs MuJoCo's kinematics on every recorded qpos and returns each
geom's world position and quaternion (w, x, y, z), so a frame is drawn by placing each mesh at
its pose. `com_positions` gives the whole-body centre of mass per frame the same way.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

VISIBLE_GROUPS = (0, 1, 2)      # MuJoCo's viewer shows geom groups 0-2 by default
DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)   # a geom's rgba when none is given (its material's then)
SEGMENTS = 16                   # around a sphere, capsule or cylinder


@dataclasses.dataclass(frozen=True)
class GeomShape:
    """One geom as a mesh in its own frame: vertices (n, 3) m, faces (m, 3) int32 (outward,
    counter-clockwise), rgba in [0, 1]."""

    geom: int
    name: str
    kind: str                   # box, sphere, capsule, cylinder, ellipsoid, mesh
    vertices: np.ndarray
    faces: np.ndarray
    rgba: tuple[float, float, float, float]


def lathe(profile: list[tuple[float, float]], segments: int = SEGMENTS):
    """(vertices, faces) of a surface of revolution about z: profile is (radius, z) from top
    to bottom; a point of radius 0 is one vertex (a pole); a point given twice is a sharp edge
    (its two rings share no face)."""
    verts, rings = [], []
    angles = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    for rho, z in profile:
        if rho == 0.0:
            verts.append((0.0, 0.0, z))
            rings.append([len(verts) - 1] * segments)
        else:
            start = len(verts)
            verts.extend((rho * np.cos(a), rho * np.sin(a), z) for a in angles)
            rings.append(list(range(start, start + segments)))
    faces = []
    for i, (top, low) in enumerate(zip(rings[:-1], rings[1:])):
        if profile[i] == profile[i + 1]:
            continue                    # a sharp edge: two rings at one place, no band
        for j in range(segments):
            k = (j + 1) % segments
            for tri in ((top[j], low[j], top[k]), (top[k], low[j], low[k])):
                if len(set(tri)) == 3:
                    faces.append(tri)
    return np.asarray(verts, np.float64), np.asarray(faces, np.int32)


def box_mesh(half: np.ndarray):
    """(vertices, faces) of a box with half-extents `half` (3,)."""
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return signs * np.asarray(half, float), np.asarray(faces, np.int32)


def _arc(radius: float, z0: float, upper: bool, n: int) -> list[tuple[float, float]]:
    """A quarter circle of `radius` centred at height z0, pole to equator (upper) or equator
    to pole."""
    th = np.linspace(0.0, np.pi / 2, n + 1)
    pts = [(radius * np.sin(t), z0 + radius * np.cos(t)) for t in th]
    pts = [(0.0, z) if i == 0 else (r, z) for i, (r, z) in enumerate(pts)]
    if upper:
        return pts
    return [(r, 2 * z0 - z) for r, z in reversed(pts)]


def primitive_mesh(kind: str, size: np.ndarray, segments: int = SEGMENTS):
    """(vertices, faces) of a MuJoCo primitive from its geom_size (MuJoCo's conventions:
    half-extents, radius, (radius, half-length along z))."""
    n = max(2, segments // 4)
    if kind == "box":
        return box_mesh(size)
    if kind in ("sphere", "ellipsoid"):
        r = float(size[0])
        v, f = lathe(_arc(r, 0.0, True, n)[:-1] + _arc(r, 0.0, False, n), segments)
        return (v * (np.asarray(size, float) / r) if kind == "ellipsoid" else v), f
    r, h = float(size[0]), float(size[1])
    if kind == "capsule":
        return lathe(_arc(r, h, True, n) + _arc(r, -h, False, n), segments)
    if kind == "cylinder":
        return lathe([(0.0, h), (r, h), (r, h), (r, -h), (r, -h), (0.0, -h)], segments)
    raise ValueError(f"no mesh for a {kind} geom")


def mesh_asset(model: mujoco.MjModel, mesh_id: int):
    """(vertices, faces) of a mesh asset, in the frame of the geoms that use it."""
    va, vn = int(model.mesh_vertadr[mesh_id]), int(model.mesh_vertnum[mesh_id])
    fa, fn = int(model.mesh_faceadr[mesh_id]), int(model.mesh_facenum[mesh_id])
    return (np.array(model.mesh_vert[va:va + vn], np.float64),
            np.array(model.mesh_face[fa:fa + fn], np.int32))


KINDS = {int(mujoco.mjtGeom.mjGEOM_BOX): "box", int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
         int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
         int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
         int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): "ellipsoid",
         int(mujoco.mjtGeom.mjGEOM_MESH): "mesh"}


def geom_rgba(model: mujoco.MjModel, g: int) -> tuple[float, float, float, float]:
    """The colour MuJoCo draws geom g with: its rgba, or its material's when it gives none."""
    rgba = tuple(float(x) for x in model.geom_rgba[g])
    mat = int(model.geom_matid[g])
    if mat >= 0 and np.allclose(rgba, DEFAULT_RGBA):
        rgba = tuple(float(x) for x in model.mat_rgba[mat])
    return rgba


def geom_shapes(model: mujoco.MjModel, groups=VISIBLE_GROUPS) -> list[GeomShape]:
    """The drawn geoms of `model` (of the given groups, not fully transparent, not on the
    world body) as meshes in their own frames."""
    shapes = []
    for g in range(model.ngeom):
        kind = KINDS.get(int(model.geom_type[g]))
        rgba = geom_rgba(model, g)
        if (kind is None or int(model.geom_group[g]) not in groups or rgba[3] <= 0.0
                or int(model.geom_bodyid[g]) == 0):
            continue
        verts, faces = (mesh_asset(model, int(model.geom_dataid[g])) if kind == "mesh"
                        else primitive_mesh(kind, model.geom_size[g]))
        shapes.append(GeomShape(g, model.geom(g).name, kind, verts, faces, rgba))
    return shapes


def mat_to_wxyz(mats: np.ndarray) -> np.ndarray:
    """(..., 9) row-major rotation matrices -> (..., 4) unit quaternions (w, x, y, z), w >= 0."""
    flat = np.asarray(mats, np.float64).reshape(-1, 9)
    out = np.empty((len(flat), 4))
    for i, m in enumerate(flat):
        mujoco.mju_mat2Quat(out[i], m)
    out *= np.where(out[:, :1] < 0, -1.0, 1.0)
    return out.reshape(np.shape(mats)[:-1] + (4,))


def geom_poses(model: mujoco.MjModel, qpos: np.ndarray, geoms) -> tuple[np.ndarray, np.ndarray]:
    """World positions (T, G, 3) and quaternions (T, G, 4) of `geoms` at each qpos (T, nq),
    from MuJoCo's forward kinematics."""
    qpos = np.atleast_2d(np.asarray(qpos, np.float64))
    geoms = np.asarray(list(geoms), int)
    data = mujoco.MjData(model)
    pos = np.empty((len(qpos), len(geoms), 3))
    mats = np.empty((len(qpos), len(geoms), 9))
    for t, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        pos[t], mats[t] = data.geom_xpos[geoms], data.geom_xmat[geoms]
    return pos, mat_to_wxyz(mats)


def com_positions(model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """(T, 3) whole-body centre of mass at each qpos (the mass-weighted subtree CoMs of the
    world's children)."""
    qpos = np.atleast_2d(np.asarray(qpos, np.float64))
    data = mujoco.MjData(model)
    roots = [b for b in range(1, model.nbody) if int(model.body_parentid[b]) == 0]
    mass = model.body_subtreemass[roots]
    out = np.empty((len(qpos), 3))
    for t, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        out[t] = mass @ data.subtree_com[roots] / mass.sum()
    return out


def site_positions(model: mujoco.MjModel, qpos: np.ndarray, sites) -> np.ndarray:
    """(T, S, 3) world positions of `sites` at each qpos."""
    qpos = np.atleast_2d(np.asarray(qpos, np.float64))
    sites = np.asarray(list(sites), int)
    data = mujoco.MjData(model)
    out = np.empty((len(qpos), len(sites), 3))
    for t, q in enumerate(qpos):
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        out[t] = data.site_xpos[sites]
    return out
