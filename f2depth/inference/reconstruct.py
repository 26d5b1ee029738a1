"""3-D reconstruction: predicted depth of a posed sequence fused into a TSDF volume (Open3D's hashed
``t.geometry.VoxelBlockGrid``), a coloured triangle mesh extracted by marching cubes, and its accuracy and
completeness against the mesh fused the same way from the reference (ground-truth) depth.

Open3D is an optional dependency (``pip install 'f2depth[recon]'``), imported when a function needs it.
(The legacy ``pipelines.integration.ScalableTSDFVolume`` of Open3D 0.20.0 returns empty meshes for any
input here, so the tensor API is used; ``UniformTSDFVolume`` works but needs the scene's bounds.)
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from f2depth.errors import DataError
from f2depth.inference.optional import require
from f2depth.inference.predict import Predictor
from f2depth.inference.scaling import median_ratio
from f2depth.inference.sequences import SequenceFrame
from f2depth.io import atomic_path

SCALINGS = ("sequence", "frame", "fixed")
DEPTH_SOURCES = ("predicted", "reference")
#: Bytes of TSDF memory per m² of observed surface, times the voxel size squared, per block of band: Open3D
#: keeps 16³-voxel blocks of 20 bytes a voxel (tsdf, weight, 3 colours: float32), and the process peaks at
#: about 2.3× the blocks' bytes (tests' box room at a 5 mm voxel, truncation 4 voxels: a band 1.2 blocks
#: thick, 686 MB of blocks, 1.6 GB more resident memory).
TSDF_BYTES_M2 = 16 * 20 * 2.3
#: The cell (m) at which the observed surface is counted (:func:`seen_area`).
AREA_CELL = 0.1


@dataclass(frozen=True)
class TSDFSettings:
    """voxel: voxel size (m); trunc: truncation distance of the signed distance (m, default 4 voxels);
    max_depth: depths beyond this (m) are not integrated; min_observations: a voxel enters the mesh
    when at least this many frames observed it."""

    voxel: float = 0.02
    trunc: float | None = None
    max_depth: float = 5.0
    min_observations: int = 1

    def __post_init__(self) -> None:
        if not (self.voxel > 0 and self.max_depth > 0 and (self.trunc is None or self.trunc > 0)):
            raise ValueError(f"voxel, trunc and max_depth must be > 0: {self}")
        if self.min_observations < 1:
            raise ValueError(f"min_observations must be ≥ 1, got {self.min_observations}")

    @property
    def sdf_trunc(self) -> float:
        return self.trunc if self.trunc is not None else 4.0 * self.voxel


def _o3d():
    return require("open3d", "3-D reconstruction (TSDF fusion)")


class TSDFFusion:
    """A coloured TSDF volume on the CPU: ``integrate`` posed RGB-D frames, then ``mesh()``."""

    BLOCK_RESOLUTION = 16  # voxels per block edge; the block hash map grows as needed

    def __init__(self, settings: TSDFSettings) -> None:
        o3d = _o3d()
        self.o3d, self.settings = o3d, settings
        f32 = o3d.core.float32
        self.grid = o3d.t.geometry.VoxelBlockGrid(attr_names=("tsdf", "weight", "color"),
                                                  attr_dtypes=(f32, f32, f32), attr_channels=(1, 1, 3),
                                                  voxel_size=settings.voxel,
                                                  block_resolution=self.BLOCK_RESOLUTION, block_count=1000,
                                                  device=o3d.core.Device("CPU:0"))
        self.frames = 0

    def integrate(self, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, world_T_cam: np.ndarray) -> None:
        """rgb (H,W,3) uint8, depth (H,W) metres (0 = none), K (3,3) pixels, world_T_cam (4,4)."""
        o3d, s = self.o3d, self.settings
        h, w = depth.shape
        if rgb.shape[:2] != (h, w):
            raise ValueError(f"rgb {rgb.shape[:2]} and depth {depth.shape} differ in size")
        tensor = o3d.core.Tensor
        d = o3d.t.geometry.Image(tensor(np.ascontiguousarray(depth, np.float32)[..., None]))
        c = o3d.t.geometry.Image(tensor(np.ascontiguousarray(rgb, np.float32) / np.float32(255.0)))
        k = tensor(np.asarray(K, np.float64))
        cam_T_world = tensor(np.linalg.inv(np.asarray(world_T_cam, np.float64)))
        multiplier, max_depth = float(s.sdf_trunc / s.voxel), float(s.max_depth)
        blocks = self.grid.compute_unique_block_coordinates(d, k, cam_T_world, 1.0, max_depth, multiplier)
        self.grid.integrate(blocks, d, c, k, k, cam_T_world, 1.0, max_depth, multiplier)
        self.frames += 1

    def mesh(self):
        """The zero level set as a legacy ``open3d.geometry.TriangleMesh`` with vertex colours in [0, 1]
        and normals (empty when nothing was observed often enough)."""
        if self.frames == 0:
            return self.o3d.geometry.TriangleMesh()
        mesh = self.grid.extract_triangle_mesh(weight_threshold=self.settings.min_observations - 0.5)
        mesh = mesh.to_legacy()
        mesh.compute_vertex_normals()
        return mesh


def write_mesh(path: str | os.PathLike, mesh) -> None:
    """Binary PLY with vertex colours and normals, written atomically."""
    o3d = _o3d()
    with atomic_path(path, suffix=".ply") as tmp:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh, write_ascii=False):
            raise OSError(f"{path}: Open3D could not write the mesh")


def surface_distance(points: np.ndarray, mesh) -> np.ndarray:
    """Exact distance (N,) from points (N,3) to the nearest point on a triangle mesh's surface (Open3D's
    ``RaycastingScene``)."""
    o3d = _o3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    query = o3d.core.Tensor(np.ascontiguousarray(points, np.float32))
    return scene.compute_distance(query).numpy().astype(np.float64)


def mesh_metrics(pred, ref, threshold: float = 0.05, samples: int = 100_000,
                 seed: int = 0) -> dict[str, float]:
    """Compare two meshes through ``samples`` points drawn uniformly (by area) on each, measured to the
    other mesh's surface.

    accuracy_mean/median: distance (m) of predicted-surface points to the reference surface;
    completeness: share of reference points within ``threshold`` of the predicted surface
    (completion_mean: their mean distance); precision: share of predicted points within ``threshold``;
    fscore: harmonic mean of precision and completeness.
    """
    o3d = _o3d()
    for name, mesh in (("predicted", pred), ("reference", ref)):
        if len(mesh.triangles) == 0:
            raise ValueError(f"the {name} mesh is empty; nothing to compare")
    o3d.utility.random.seed(seed)
    d_pr = surface_distance(np.asarray(pred.sample_points_uniformly(samples).points), ref)
    d_rp = surface_distance(np.asarray(ref.sample_points_uniformly(samples).points), pred)
    precision, completeness = float(np.mean(d_pr < threshold)), float(np.mean(d_rp < threshold))
    f = 2 * precision * completeness / (precision + completeness) if precision + completeness > 0 else 0.0
    return {"accuracy_mean": float(d_pr.mean()), "accuracy_median": float(np.median(d_pr)),
            "completeness": completeness, "completion_mean": float(d_rp.mean()),
            "precision": precision, "fscore": float(f), "threshold": threshold, "samples": samples}


def frame_scales(ratios: Sequence[float | None], scaling: str, scale: float = 1.0) -> list[float]:
    """Per-frame depth factors: ``fixed`` → ``scale`` everywhere; ``frame`` → each frame's median ratio;
    ``sequence`` → the median of the frames' ratios for all (one consistent scale)."""
    if scaling not in SCALINGS:
        raise ValueError(f"scaling must be one of {SCALINGS}, got {scaling!r}")
    if scaling == "fixed":
        return [float(scale)] * len(ratios)
    if any(r is None for r in ratios):
        raise ValueError(f"scaling '{scaling}' needs a reference depth for every frame")
    if scaling == "frame":
        return [float(r) for r in ratios]
    return [float(np.median(ratios))] * len(ratios)


def seen_area(frames: Sequence[SequenceFrame], depths: Sequence[np.ndarray], scales: Sequence[float],
              max_depth: float, stride: int = 2) -> float:
    """The surface (m²) the frames see within ``max_depth``: every ``stride``-th pixel of each depth (H,W)
    metres × its scale back-projected to the world, counted in cells of ``AREA_CELL`` m (each distinct cell
    a wall crosses counts ``AREA_CELL``² of surface)."""
    cells = []
    for f, depth, k in zip(frames, depths, scales):
        z = np.asarray(depth, np.float64)[::stride, ::stride] * k
        v, u = np.mgrid[0:depth.shape[0]:stride, 0:depth.shape[1]:stride]
        ok = np.isfinite(z) & (z > 0) & (z <= max_depth)
        K, T = np.asarray(f.K, np.float64), np.asarray(f.world_T_cam, np.float64)
        x, y = (u[ok] - K[0, 2]) / K[0, 0] * z[ok], (v[ok] - K[1, 2]) / K[1, 1] * z[ok]
        world = np.stack([x, y, z[ok]], -1) @ T[:3, :3].T + T[:3, 3]
        cells.append(np.unique(np.floor(world / AREA_CELL).astype(np.int64), axis=0))
    found = np.unique(np.concatenate(cells), axis=0) if cells else np.zeros((0, 3))
    return len(found) * AREA_CELL ** 2


def memory_budget() -> int:
    """Bytes the TSDF volumes may take: half of this machine's physical memory (4 GiB where unknown)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")) // 2
    except (ValueError, OSError, AttributeError):
        return 4 << 30


def tsdf_bytes(area: float, voxel: float, trunc: float | None = None) -> float:
    """The memory (bytes) of a TSDF of ``area`` m² of surface at ``voxel`` m with truncation ``trunc`` m
    (default 4 voxels): the blocks of a band 0.8 · (1 + trunc / 8 voxels) blocks thick (1.2 at 4 voxels)."""
    trunc = 4 * voxel if trunc is None else trunc
    return area * TSDF_BYTES_M2 * 0.8 * (1 + trunc / (8 * voxel)) / voxel ** 2


def check_voxel(area: float, tsdf: TSDFSettings, volumes: int = 1, budget: int | None = None) -> None:
    """DataError naming ``--voxel`` when ``volumes`` TSDFs of ``area`` m² of surface would need more than
    ``budget`` bytes (default :func:`memory_budget`), with the smallest voxel that fits."""
    why = " (half of this machine's memory)" if budget is None else ""
    budget = memory_budget() if budget is None else budget
    voxel = tsdf.voxel
    need = volumes * tsdf_bytes(area, voxel, tsdf.trunc)
    if need > budget:
        lo, hi = voxel, max(voxel, 1.0)
        while volumes * tsdf_bytes(area, hi, tsdf.trunc) > budget:
            hi *= 2
        for _ in range(60):  # the memory falls as the voxel grows: bisect for the smallest that fits
            mid = (lo + hi) / 2
            lo, hi = (lo, mid) if volumes * tsdf_bytes(area, mid, tsdf.trunc) <= budget else (mid, hi)
        smallest = hi
        raise DataError("--voxel", f"a {voxel:g} m voxel needs about {need / 1e9:.3g} GB for the "
                        f"{area:.0f} m² of surface these frames see ({volumes} volume(s)), more than the "
                        f"{budget / 1e9:.3g} GB allowed{why}",
                        f"the smallest voxel here is {math.ceil(smallest * 1e4) / 1e4:g} m")


@dataclass(frozen=True)
class ReconstructSettings:
    output: Path
    tsdf: TSDFSettings = TSDFSettings()
    scaling: str = "sequence"
    scale: float = 1.0
    depth_source: str = "predicted"
    evaluate: bool = False
    reference_mesh: Path | None = None
    threshold: float = 0.05
    batch_size: int = 4
    progress: bool | None = None


def _predicted(frames: Sequence[SequenceFrame], predictor: Predictor | None, s: ReconstructSettings,
               need_ref: bool) -> tuple[list[np.ndarray], list[float | None]]:
    """Depth (H,W) per frame (predicted or the reference) and its median ratio to the reference."""
    depths: list[np.ndarray] = []
    ratios: list[float | None] = []
    bar = tqdm(total=len(frames), desc="depth", unit="frame",
               disable=None if s.progress is None else not s.progress)
    try:
        for start in range(0, len(frames), s.batch_size):
            chunk = frames[start:start + s.batch_size]
            rgbs = [f.rgb() for f in chunk]
            refs = [f.reference_depth(r.shape[:2]) if need_ref else None for f, r in zip(chunk, rgbs)]
            preds = (list(refs) if s.depth_source == "reference"
                     else predictor.predict(rgbs, [str(f.image) for f in chunk]))
            for f, pred, ref in zip(chunk, preds, refs):
                ratios.append(None if ref is None else median_ratio(pred, ref, str(f.reference)))
                depths.append(pred)
            bar.update(len(chunk))
    finally:
        bar.close()
    return depths, ratios


def reconstruct(frames: Sequence[SequenceFrame], predictor: Predictor | None,
                settings: ReconstructSettings) -> dict[str, Any]:
    """Fuse the sequence and write the mesh (and optionally the reference mesh); returns a summary with
    the scale(s) used, mesh sizes and, with ``evaluate``, :func:`mesh_metrics` against the reference."""
    s = settings
    if not frames:
        raise ValueError("no frames to reconstruct")
    if s.depth_source not in DEPTH_SOURCES:
        raise ValueError(f"depth_source must be one of {DEPTH_SOURCES}, got {s.depth_source!r}")
    if s.depth_source == "predicted" and predictor is None:
        raise ValueError("a predictor is needed for depth_source='predicted'")
    _o3d()  # fail before the long prediction pass when Open3D is missing
    t0 = time.perf_counter()
    with_ref = s.evaluate or s.reference_mesh is not None
    need_ref = with_ref or s.scaling != "fixed" or s.depth_source == "reference"
    missing = [f.image for f in frames if need_ref and f.reference is None]
    if missing:
        raise DataError(missing[0], "no reference depth for this frame",
                        "use --scaling fixed --scale S, or give a sequence with depth / ground truth")
    depths, ratios = _predicted(frames, predictor, s, need_ref)
    scales = frame_scales(ratios, s.scaling if s.depth_source == "predicted" else "fixed",
                          s.scale if s.depth_source == "predicted" else 1.0)
    check_voxel(seen_area(frames, depths, scales, s.tsdf.max_depth), s.tsdf, 2 if with_ref else 1)
    fused = TSDFFusion(s.tsdf)
    ref_fused = TSDFFusion(s.tsdf) if with_ref else None
    for f, depth, k in zip(frames, depths, tqdm(list(scales), desc="fuse", unit="frame",
                                                disable=None if s.progress is None else not s.progress)):
        rgb = f.rgb()
        fused.integrate(rgb, depth * np.float32(k), f.K, f.world_T_cam)
        if ref_fused is not None:
            ref_fused.integrate(rgb, f.reference_depth(rgb.shape[:2]), f.K, f.world_T_cam)
    mesh = fused.mesh()
    if len(mesh.triangles) == 0:
        raise DataError(s.output, "the fused volume has no surface",
                        f"check the depth scale (factors {min(scales):.3g}..{max(scales):.3g}) and "
                        "--max-depth")
    write_mesh(s.output, mesh)
    summary: dict[str, Any] = {
        "output": str(s.output), "frames": len(frames), "depth_source": s.depth_source,
        "scaling": s.scaling if s.depth_source == "predicted" else "none",
        "scale_median": float(np.median(scales)), "scale_min": min(scales), "scale_max": max(scales),
        "voxel": s.tsdf.voxel, "sdf_trunc": s.tsdf.sdf_trunc, "max_depth": s.tsdf.max_depth,
        "vertices": len(mesh.vertices), "triangles": len(mesh.triangles),
    }
    if ref_fused is not None:
        ref_mesh = ref_fused.mesh()
        if len(ref_mesh.triangles) == 0:
            raise DataError(frames[0].reference or frames[0].image, "the reference depth fuses to no surface",
                            "check --max-depth against the reference depth's range")
        if s.reference_mesh is not None:
            write_mesh(s.reference_mesh, ref_mesh)
        summary["reference_vertices"] = len(ref_mesh.vertices)
        if s.evaluate:
            summary["metrics"] = mesh_metrics(mesh, ref_mesh, threshold=s.threshold)
    summary["seconds"] = time.perf_counter() - t0
    return summary

