"""Running one :class:`~f2depth.synth.plan.Job`: build (or reuse) the room, move the camera, render every
frame, write it in its dataset's format plus the side-car ground truth, and return summary numbers."""

from __future__ import annotations

import functools
import time

import cv2
import numpy as np

from f2depth.camera import NYU_RGB_DIST, NYU_RGB_K, distortion_maps
from f2depth.formats.sevenscenes import SEVENSCENES_K
from f2depth.formats.sintel import write_flo
from f2depth.io import write_rgb
from f2depth.synth import writers
from f2depth.synth.camera_path import PathStyle, handheld_path
from f2depth.synth.config import OutputPaths, SynthConfig
from f2depth.synth.groundtruth import kinect_raw_depth, occlusion, relative_pose, rigid_flow
from f2depth.synth.layout import build
from f2depth.synth.plan import Job, rng_for
from f2depth.synth.render import render
from f2depth.synth.scene import Scene
from f2depth.synth.sensor import expose, exposure_series, vignette_map
from f2depth.synth.styles import STYLES

STYLE_OF = {"nyu_raw": "nyu", "nyu_labeled": "nyu", "sevenscenes": "sevenscenes", "campus": "campus",
            "animated": "animated"}
PATHS = {
    "nyu": PathStyle(),
    "sevenscenes": PathStyle(pitch=(-30.0, -5.0)),
    "campus": PathStyle(height=(1.4, 1.7), pitch=(-12.0, 5.0), wall_margin=0.5, radius=(0.2, 0.5)),
    "animated": PathStyle(fps=24.0, speed=(1.0, 2.2), speed_wobble=0.2, radius=(0.5, 1.4),
                          pitch=(-20.0, 10.0), pitch_amp=(3.0, 8.0), roll=(-8.0, 8.0), roll_amp=(2.0, 6.0),
                          pan_amp=(15.0, 35.0), pan_freq=(0.2, 0.5), tremor=0.8, wall_margin=0.5,
                          obstacle_margin=0.3),
}
NYU_EPOCH = 1_294_000_000.0  # raw timestamps start in early 2011, as NYU's do


@functools.lru_cache(maxsize=3)
def room(style: str, kind: str, name: str, seed: int) -> Scene:
    """The room called ``name``: identical wherever and whenever it is built."""
    return build(style, kind, name, rng_for(seed, "room", style, name))


@functools.lru_cache(maxsize=1)
def _nyu_distortion_maps() -> tuple[np.ndarray, np.ndarray]:
    return distortion_maps(NYU_RGB_K, NYU_RGB_DIST, (480, 640))


def intrinsics(job: Job, cfg: SynthConfig) -> np.ndarray:
    if job.dataset in ("nyu_raw", "nyu_labeled"):
        return NYU_RGB_K.copy()
    if job.dataset == "sevenscenes":
        return SEVENSCENES_K.copy()
    h, w = job.hw
    f = cfg.campus_focal if job.dataset == "campus" else 0.75 * w
    return np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])


class _Sensor:
    """Per-sequence camera state: exposure series, vignetting, noise level, per-frame noise streams."""

    def __init__(self, job: Job, cfg: SynthConfig, K: np.ndarray, n: int):
        style = STYLES[STYLE_OF[job.dataset]]
        rng = rng_for(cfg.seed, job.dataset, job.room, job.seq, "sensor")
        self.on, self.cfg, self.job = cfg.sensor_effects, cfg, job
        self.gains = exposure_series(n, rng, style.exposure_jitter) if self.on else np.ones(n)
        self.vignette = vignette_map(K, job.hw, rng.uniform(*style.vignetting)) if self.on else None
        self.noise = rng.uniform(*style.noise) if self.on else 0.0

    def frame_rng(self, k: int, what: str = "noise") -> np.random.Generator:
        return rng_for(self.cfg.seed, self.job.dataset, self.job.room, self.job.seq, what, k)

    def __call__(self, radiance: np.ndarray, exposure: float, k: int, what: str = "noise") -> np.ndarray:
        return expose(radiance, exposure * self.gains[k], self.vignette, self.noise, self.frame_rng(k, what))


def run(job: Job, cfg: SynthConfig, paths: OutputPaths) -> dict:
    """Generate everything of ``job``; returns counts and sums for the metrics (labeled: the arrays too)."""
    t0 = time.perf_counter()
    scene = room(STYLE_OF[job.dataset], job.kind, job.room, cfg.seed)
    out = (_views if job.dataset in ("campus", "nyu_labeled") else _sequence)(job, cfg, paths, scene)
    out.update(dataset=job.dataset, room=job.room, seq=job.seq, seconds=time.perf_counter() - t0)
    return out


def _sequence(job: Job, cfg: SynthConfig, paths: OutputPaths, scene: Scene) -> dict:
    K, n = intrinsics(job, cfg), job.frames
    style = STYLE_OF[job.dataset]
    poses, times = handheld_path(scene, n, rng_for(cfg.seed, job.dataset, job.room, job.seq, "path"),
                                 PATHS[style])
    sensor = _Sensor(job, cfg, K, n)
    gt_dir = paths.synth_gt / job.dataset / job.room / (job.seq if job.dataset == "sevenscenes" else "")
    stems = _stems(job, cfg, times)
    stats = {"frames": n, "flow_abs_sum": 0.0, "flow_count": 0, "occluded_sum": 0, "depth_sum": 0.0,
             "depth_count": 0, "speeds": np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).tolist(),
             "fps": PATHS[style].fps}
    prev_depth = None
    for k in range(n):
        radiance, depth = render(scene, poses[k], K, job.hw, cfg.supersample)
        if job.dataset == "nyu_raw":
            mx, my = _nyu_distortion_maps()
            distorted = cv2.remap(radiance, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            rgb = sensor(distorted, scene.exposure, k)
            write_rgb(paths.nyu_raw / job.room / f"{stems[k]}.ppm", rgb)
        elif job.dataset == "sevenscenes":
            rgb = sensor(radiance, scene.exposure, k)
            base = paths.sevenscenes / job.room / job.seq / stems[k]
            write_rgb(f"{base}.color.png", rgb)
            raw = kinect_raw_depth(depth, rgb, sensor.frame_rng(k, "holes"))
            writers.write_depth_mm(f"{base}.depth.png", raw)
            writers.write_pose_txt(f"{base}.pose.txt", poses[k])
        else:
            base = paths.animated / "training"
            rgb = sensor(radiance, scene.exposure, k)
            write_rgb(base / "clean" / job.room / f"{stems[k]}.png", rgb)
            final = _degrade(radiance, depth, rng_for(cfg.seed, job.dataset, job.room, "final"))
            write_rgb(base / "final" / job.room / f"{stems[k]}.png",
                              sensor(final, scene.exposure, k, "final-noise"))
        if prev_depth is not None:
            _write_pair(job, cfg, paths, gt_dir, stems[k - 1], prev_depth, depth, poses[k - 1:k + 1], K,
                        stats)
        prev_depth = depth
        stats["depth_sum"] += float(depth.sum(dtype=np.float64))
        stats["depth_count"] += depth.size
    writers.write_gt(gt_dir / f"{stems[-1]}.npz", prev_depth, poses[-1], K, compress=cfg.compress_gt)
    return stats


def _write_pair(job, cfg, paths, gt_dir, stem, depth, depth_next, poses, K, stats) -> None:
    """Ground truth of a frame with a successor: flow + occlusion (in the side-car with ``flow_gt`` and always
    for the animated set, which also gets Sintel's .flo / occlusion png)."""
    flow, z_next = rigid_flow(depth, K, relative_pose(poses[0], poses[1]))
    occ = occlusion(flow, z_next, depth_next)
    stored = cfg.flow_gt or job.dataset == "animated"
    writers.write_gt(gt_dir / f"{stem}.npz", depth, poses[0], K, flow if stored else None,
                     occ if stored else None, cfg.compress_gt)
    if job.dataset == "animated":
        write_flo(paths.animated / "training" / "flow" / job.room / f"{stem}.flo", flow)
        writers.write_mask(paths.animated / "training" / "occlusions" / job.room / f"{stem}.png", occ)
    stats["flow_abs_sum"] += float(np.linalg.norm(flow, axis=2).sum(dtype=np.float64))
    stats["flow_count"] += flow.shape[0] * flow.shape[1]
    stats["occluded_sum"] += int(occ.sum())


def _stems(job: Job, cfg: SynthConfig, times: np.ndarray) -> list[str]:
    if job.dataset == "nyu_raw":
        rng = rng_for(cfg.seed, job.dataset, job.room, "clock")
        start = NYU_EPOCH + float(rng.integers(0, 40_000_000)) + float(rng.integers(0, 1_000_000)) / 1e6
        counter = int(rng.integers(1, 4_000_000_000 - 10 * len(times)))
        return [f"r-{start + t:.6f}-{counter + k}" for k, t in enumerate(times)]
    if job.dataset == "sevenscenes":
        return [f"frame-{k:06d}" for k in range(len(times))]
    return [f"frame_{k + 1:04d}" for k in range(len(times))]


def _degrade(radiance: np.ndarray, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Sintel 'final'-like pass: depth fog, defocus and a directional motion blur (fixed per sequence)."""
    fog_color = radiance.reshape(-1, 3).mean(axis=0) * rng.uniform(0.9, 1.4)
    a = rng.uniform(0.2, 0.5) * (1.0 - np.exp(-depth / rng.uniform(3.0, 8.0)))
    out = radiance * (1.0 - a[..., None]) + fog_color * a[..., None]
    length, angle = rng.uniform(2.0, 6.0), rng.uniform(0, np.pi)
    ksize = int(np.ceil(length)) * 2 + 1
    kernel = np.zeros((ksize, ksize), np.float32)
    c = ksize // 2
    dx, dy = np.cos(angle) * length / 2, np.sin(angle) * length / 2
    cv2.line(kernel, (round(c - dx), round(c - dy)), (round(c + dx), round(c + dy)), 1.0, 1, cv2.LINE_AA)
    out = cv2.filter2D(out.astype(np.float32), -1, kernel / kernel.sum(), borderType=cv2.BORDER_REFLECT)
    return cv2.GaussianBlur(out, (0, 0), rng.uniform(0.4, 1.0))


def _views(job: Job, cfg: SynthConfig, paths: OutputPaths, scene: Scene) -> dict:
    """Single views: campus images (+ measured points) or labeled images (arrays returned)."""
    K = intrinsics(job, cfg)
    style = STYLE_OF[job.dataset]
    sensor = _Sensor(job, cfg, K, len(job.items))
    stats = {"frames": len(job.items), "depth_sum": 0.0, "depth_count": 0, "points": [], "labeled": []}
    for k, item in enumerate(job.items):
        rng = rng_for(cfg.seed, job.dataset, job.room, "view", str(item))
        pose = _composed_view(scene, rng, PATHS[style], K, job.hw)
        radiance, depth = render(scene, pose, K, job.hw, cfg.supersample)
        rgb = sensor(radiance, scene.exposure, k)
        if job.dataset == "campus":
            write_rgb(paths.campus / job.room / f"{item}.jpg", rgb, jpeg_quality=92)
            writers.write_gt(paths.synth_gt / "campus" / job.room / f"{item}.npz", depth, pose, K,
                             compress=cfg.compress_gt)
            pts = campus_points(depth, rng, int(rng.integers(13, 17)))
            stats["points"] += [(job.room, item, u, v, d) for u, v, d in pts]
        else:
            raw = kinect_raw_depth(depth, rgb, rng)
            writers.write_gt(paths.synth_gt / "nyu_labeled" / job.room / f"{item:04d}.npz", depth, pose, K,
                             compress=cfg.compress_gt)
            stats["labeled"].append((item, rgb, depth, raw))
        stats["depth_sum"] += float(depth.sum(dtype=np.float64))
        stats["depth_count"] += depth.size
    return stats


def _composed_view(scene: Scene, rng: np.random.Generator, style: PathStyle, K: np.ndarray, hw, tries=6):
    """A single photo's pose: of a few handheld poses, the one whose view spans the widest depth range
    (a photographer frames the room, not a wall at arm's length); judged on a 1/8-size depth render."""
    Ks = K.copy()
    Ks[:2] /= 8
    small = (max(8, hw[0] // 8), max(8, hw[1] // 8))
    best, best_score = None, -1.0
    for _ in range(tries):
        pose = handheld_path(scene, 1, rng, style)[0][0]
        depth = render(scene, pose, Ks, small, 1)[1]
        lo, hi = np.quantile(depth, [0.1, 0.9])
        if hi / lo > best_score:
            best, best_score = pose, hi / lo
    return best


def campus_points(depth: np.ndarray, rng: np.random.Generator, n: int) -> list[tuple[int, int, float]]:
    """``n`` integer pixels (u, v, z-depth) at least 4 px from depth edges and away from the borders,
    one per depth quantile bin so they spread from near to far, at least 12 px apart."""
    h, w = depth.shape
    logd = np.log(depth)
    edge = np.zeros((h, w), np.uint8)
    edge[:, 1:] |= np.abs(np.diff(logd, axis=1)) > 0.03  # depth discontinuities, not slanted planes
    edge[1:, :] |= np.abs(np.diff(logd, axis=0)) > 0.03
    ok = cv2.dilate(edge, np.ones((9, 9), np.uint8)) == 0
    m = max(8, min(h, w) // 20)
    ok[:m], ok[-m:], ok[:, :m], ok[:, -m:] = False, False, False, False
    v, u = np.nonzero(ok)
    if u.size < n:
        raise ValueError(f"only {u.size} smooth pixels to place {n} campus points")
    order = np.argsort(depth[v, u], kind="stable")
    bins = np.array_split(order, n)
    chosen: list[tuple[int, int, float]] = []
    for b in bins:
        for i in rng.permutation(b)[:50]:
            if all((u[i] - cu) ** 2 + (v[i] - cv) ** 2 >= 144 for cu, cv, _ in chosen):
                chosen.append((int(u[i]), int(v[i]), float(depth[v[i], u[i]])))
                break
    for i in rng.permutation(u.size):  # bins where every try was too close to a chosen point
        if len(chosen) >= n:
            break
        if all((u[i] - cu) ** 2 + (v[i] - cv) ** 2 >= 144 for cu, cv, _ in chosen):
            chosen.append((int(u[i]), int(v[i]), float(depth[v[i], u[i]])))
    return sorted(chosen, key=lambda p: p[2])
