"""The static scene of a twin: moving points left out, then a trimmed Poisson surface of the rest.

All coordinates in the map frame (m). Steps:

1. :func:`moving_points`: a point of one frame is *moving* when another frame's beam in its
   direction measured a range clearly beyond it (that frame saw through the place where the point
   was: free space; Schauer & Nuechter's ray-tracing idea, done as a range-image lookup). Each frame
   is checked against its ``neighbours`` nearest frames in time. One frame: nothing to compare with,
   nothing is removed.
2. :func:`reconstruct_mesh`: voxel-downsampled points, normals from their neighbours (Open3D,
   oriented towards the sensor that saw each point), screened Poisson reconstruction (Kazhdan & Hoppe
   2013) of depth ``poisson_depth``, then trimmed so the surface does not balloon beyond the points:
   vertices of the lowest ``density_quantile`` of Poisson densities go, and so do triangles with a
   vertex farther from the nearest point, or an edge longer, than the local point spacing allows
   (spacing = range x the angle between neighbouring beams, at least ``voxel_m``). For a sector split a
   second, coarser Poisson surface (``bridge_depth``) fills the held-out sectors: its triangles there may lie
   as far from the calibration points as the arc to the nearest calibration sector (``bridge``).
3. :func:`gap_fill_points`: before step 2, for a sector split whose held-out sectors are narrow, each
   channel's two returns on either side of a held-out gap are joined by a straight line when they lie on one
   surface (their distance no more than ``max_stretch`` times the arc between them), and points along it at the
   profile's column spacing join the calibration points: a range image's interpolation across the gap, which
   a surface seen from one place allows and Poisson's smoothing of the gap does not reproduce.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class ReconstructionSettings:
    voxel_m: float = 0.05  # downsampling of the merged points (m)
    normal_neighbours: int = 20
    poisson_depth: int = 11
    density_quantile: float = 0.02
    max_distance_spacings: float = 3.0  # a vertex may lie this many local spacings from the nearest point
    min_distance_m: float = 0.15  # ... but at least this far (m)
    max_edge_spacings: float = 8.0  # edge length limit in local spacings (at least 4 voxels)
    bridge_depth: int = 9  # Poisson depth of the surface across a sector split's held-out sectors
    seed: int = 0


@dataclass(frozen=True)
class FrameCloud:
    """One frame in the map frame: points (N, 3) m, their sensor origins (N, 3) m, the sensor pose at the
    frame's middle (4x4 sensor -> map) and the points' channels (N,)."""

    xyz: np.ndarray
    origins: np.ndarray
    pose: np.ndarray
    channel: np.ndarray


def moving_points(frames: list[FrameCloud], elevation_rad: np.ndarray, columns: int, neighbours: int = 2,
                  margin_m: float = 0.3, margin_fraction: float = 0.03) -> list[np.ndarray]:  # fmt: skip
    """Boolean mask per frame of its moving points (module doc, step 1). ``elevation_rad`` (channels,) is the
    profile's elevation per channel, ``columns`` its columns per 360 deg; a point is seen through when the
    other frame's farthest return of that channel and of the column and its two neighbours (all three) lies
    beyond its range + ``margin_m`` + ``margin_fraction`` x range."""
    out = [np.zeros(len(f.xyz), dtype=bool) for f in frames]
    if len(frames) < 2:
        return out
    images = [_range_image(f, elevation_rad, columns) for f in frames]
    for i, frame in enumerate(frames):
        others = sorted(range(len(frames)), key=lambda j: abs(j - i))[1 : neighbours + 1]
        for j in others:
            seen_through = _seen_through(frame.xyz, frames[j].pose, images[j], elevation_rad, columns,
                                         margin_m, margin_fraction)  # fmt: skip
            out[i] |= seen_through
    return out


def _range_image(frame: FrameCloud, elevation_rad: np.ndarray, columns: int) -> np.ndarray:
    """(channels, columns) farthest range (m) per cell of a frame, in its mid-frame sensor frame; 0 = no return."""
    local = (frame.xyz - frame.pose[:3, 3]) @ frame.pose[:3, :3]
    r = np.linalg.norm(local, axis=1)
    col = _column(local, columns)
    image = np.zeros((len(elevation_rad), columns))
    np.maximum.at(image, (frame.channel.astype(np.int64), col), r)
    return image


def _column(local: np.ndarray, columns: int) -> np.ndarray:
    az = np.arctan2(local[:, 1], local[:, 0])
    return (np.floor((az + np.pi) / (2 * np.pi) * columns).astype(np.int64)) % columns


def _seen_through(xyz, pose, image, elevation_rad, columns, margin_m, margin_fraction) -> np.ndarray:
    local = (xyz - pose[:3, 3]) @ pose[:3, :3]
    r = np.linalg.norm(local, axis=1)
    elevation = np.arctan2(local[:, 2], np.hypot(local[:, 0], local[:, 1]))
    order = np.argsort(elevation_rad)
    k = np.clip(np.searchsorted(elevation_rad[order], elevation), 1, len(order) - 1)
    lower, upper = order[k - 1], order[k]
    channel = np.where(elevation - elevation_rad[lower] < elevation_rad[upper] - elevation, lower, upper)
    step = np.median(np.diff(elevation_rad[order])) if len(order) > 1 else np.radians(1.0)
    inside = np.abs(elevation - elevation_rad[channel]) <= 0.5 * step + 1e-9
    col = _column(local, columns)
    beyond = r + margin_m + margin_fraction * r
    far = np.ones(len(xyz), dtype=bool)
    for dc in (-1, 0, 1):
        far &= image[channel, (col + dc) % columns] > beyond
    return far & inside


def gap_fill_points(frame: FrameCloud, columns: int, max_gap_rad: float, max_stretch: float = 4.0) -> np.ndarray:
    """Points (M, 3) m in the map frame along each channel's azimuth gaps of ``frame`` (module doc, step 3): a gap
    wider than 1.5 columns (of ``columns`` per 360 deg) and at most ``max_gap_rad`` between two consecutive returns
    of one channel is spanned when the returns are at most ``max_stretch`` x (mean range x gap angle) apart."""
    local = (frame.xyz - frame.pose[:3, 3]) @ frame.pose[:3, :3]
    az = np.arctan2(local[:, 1], local[:, 0])
    order = np.lexsort((az, frame.channel))
    ch, az, xyz = frame.channel[order], az[order], frame.xyz[order]
    gap = np.diff(az)
    step = 2 * np.pi / columns
    r = np.linalg.norm(local[order], axis=1)
    arc = 0.5 * (r[1:] + r[:-1]) * gap
    apart = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    ok = (ch[1:] == ch[:-1]) & (gap > 1.5 * step) & (gap <= max_gap_rad) & (apart <= max_stretch * arc)
    first = np.flatnonzero(ok)
    inserts = np.rint(gap[first] / step).astype(np.int64) - 1
    pair = np.repeat(first, inserts)
    k = np.arange(len(pair)) - np.repeat(np.cumsum(inserts) - inserts, inserts) + 1
    t = (k / np.repeat(inserts + 1, inserts))[:, None]
    return xyz[pair] * (1.0 - t) + xyz[pair + 1] * t


def estimate_normals(xyz: np.ndarray, origins: np.ndarray, neighbours: int = 20):
    """An Open3D point cloud of ``xyz`` with unit normals from its ``neighbours`` nearest points, each
    turned towards the sensor origin that saw the point."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=neighbours))
    normals = np.asarray(cloud.normals)
    flip = np.einsum("ij,ij->i", normals, origins - xyz) < 0
    normals[flip] *= -1.0
    cloud.normals = o3d.utility.Vector3dVector(normals)
    return cloud


def downsample(xyz: np.ndarray, origins: np.ndarray, voxel_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One point per ``voxel_m`` voxel (the first of each; deterministic): points, origins and their indices."""
    keys = np.floor(xyz / voxel_m).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    first = np.sort(first)
    return xyz[first], origins[first], first


def reconstruct_mesh(xyz: np.ndarray, origins: np.ndarray, angular_step_rad: float,
                     settings: ReconstructionSettings = ReconstructionSettings(),
                     bridge: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Vertices (V, 3) m and triangles (T, 3) of the static surface through ``xyz`` (module doc, step 2);
    ``angular_step_rad`` is the larger of the profile's horizontal and vertical beam spacing. ``bridge(vertices)``
    (m, (V,)) widens the trim where the surface may continue beyond the points: a sector split's held-out
    sectors, which Poisson's smooth surface spans from the calibration sectors around them."""
    import open3d as o3d

    if not (np.isfinite(xyz).all() and np.isfinite(origins).all()):  # Open3D would abort or hang on them
        raise ValueError("twin: non-finite points or sensor origins reached the mesh step")
    pts, org, _ = downsample(xyz, origins, settings.voxel_m)
    if len(pts) < 10:
        raise ValueError(f"twin: {len(pts)} static points after downsampling: too few to reconstruct a surface")
    cloud = estimate_normals(pts, org, settings.normal_neighbours)
    o3d.utility.random.seed(settings.seed)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            cloud, depth=settings.poisson_depth, n_threads=2)  # fmt: skip
    tree = cKDTree(pts)
    spacing = np.maximum(np.linalg.norm(pts - org, axis=1) * angular_step_rad, settings.voxel_m)
    vertices, triangles = _trimmed(mesh, np.asarray(density), tree, spacing, settings, bridge, detail=True)
    if bridge is not None:  # the held-out sectors: a coarser, smoother surface spans them
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            coarse, density = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
                cloud, depth=settings.bridge_depth, n_threads=2)  # fmt: skip
        v2, t2 = _trimmed(coarse, np.asarray(density), tree, spacing, settings, bridge)
        vertices, triangles = np.concatenate([vertices, v2]), np.concatenate([triangles, t2 + len(vertices)])
    return vertices, triangles


def _trimmed(mesh, density: np.ndarray, tree: cKDTree, spacing: np.ndarray, settings: ReconstructionSettings,
             bridge: Callable[[np.ndarray], np.ndarray] | None, detail: bool = False) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A Poisson mesh without its low-density vertices and its triangles beyond the points (module doc), or as far
    beyond them as ``bridge`` allows; the coarse bridging mesh (``detail`` False) keeps only triangles inside
    the held-out sectors (every vertex with extra distance > 0)."""
    mesh.remove_vertices_by_mask(density < np.quantile(density, settings.density_quantile))
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    distance, nearest = tree.query(vertices, workers=2)
    allowed = np.maximum(settings.max_distance_spacings * spacing[nearest], settings.min_distance_m)
    extra = np.zeros(len(vertices)) if bridge is None else bridge(vertices)
    ok_vertex = distance <= allowed + extra
    if bridge is not None and not detail:
        ok_vertex &= extra > 0
    v = vertices[triangles]
    edges = np.linalg.norm(v - np.roll(v, 1, axis=1), axis=2).max(axis=1)
    edge_limit = np.maximum(settings.max_edge_spacings * np.max(spacing[nearest][triangles], axis=1),
                            0.5 * extra[triangles].max(axis=1))  # fmt: skip
    keep = ok_vertex[triangles].all(axis=1) & (edges <= np.maximum(edge_limit, 4 * settings.voxel_m))
    triangles = triangles[keep]
    used, remap = np.unique(triangles, return_inverse=True)
    return vertices[used], remap.reshape(-1, 3).astype(np.int64)


def distances_to_mesh(vertices: np.ndarray, triangles: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Unsigned distance (N,) m from each point to the mesh (Open3D RaycastingScene)."""
    if not len(xyz):
        return np.zeros(0)
    scene = _raycasting_scene(vertices, triangles)
    import open3d as o3d

    return scene.compute_distance(o3d.core.Tensor(xyz.astype(np.float32))).numpy().astype(np.float64)


def closest_triangles(vertices: np.ndarray, triangles: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    """Index (N,) of the triangle nearest to each point."""
    import open3d as o3d

    scene = _raycasting_scene(vertices, triangles)
    result = scene.compute_closest_points(o3d.core.Tensor(xyz.astype(np.float32)))
    return result["primitive_ids"].numpy().astype(np.int64)


def _raycasting_scene(vertices: np.ndarray, triangles: np.ndarray):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(triangles.astype(np.uint32)))
    return scene
