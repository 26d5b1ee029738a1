"""Smooth handheld camera paths that stay inside the room and away from walls and furniture.

The camera centre runs along a closed random loop (a few low harmonics) around a free spot of the room,
at a speed drawn per sequence (20–40 cm/s for the indoor sets) with a slow ±10 % wobble and a small
vertical bob; arc-length parametrisation keeps the speed under control for any sequence length. The
orientation tracks a point of interest in the room, with slow panning, pitch and roll oscillations and
a faint hand tremor: every angle is a sum of sinusoids, so the motion is smooth and has real
yaw/pitch/roll.

World frame z up; camera frame x right, y down, z forward; poses ``world_T_cam`` (4, 4) float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from f2depth.synth.scene import Scene

#: camera axes in the world for yaw = pitch = roll = 0 (looking along +x): columns right, down, forward
_R_BASE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class PathStyle:
    """Ranges (min, max) the path of one sequence is drawn from; angles in degrees, speeds in m/s."""

    fps: float = 30.0
    speed: tuple[float, float] = (0.24, 0.34)
    speed_wobble: float = 0.1
    height: tuple[float, float] = (1.15, 1.6)
    bob: float = 0.008  # vertical bob amplitude (m) at ~0.8 Hz
    radius: tuple[float, float] = (0.25, 0.7)
    pitch: tuple[float, float] = (-25.0, -5.0)
    pitch_amp: tuple[float, float] = (1.5, 5.0)
    roll: tuple[float, float] = (-4.0, 4.0)
    roll_amp: tuple[float, float] = (0.5, 2.5)
    pan_amp: tuple[float, float] = (5.0, 15.0)
    pan_freq: tuple[float, float] = (0.1, 0.3)
    tremor: float = 0.25
    wall_margin: float = 0.6
    obstacle_margin: float = 0.4


def rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """world_R_cam for yaw about world z, pitch (positive looks up) and roll about the optical axis (rad)."""
    cy, sy, cp, sp, cr, sr = (np.cos(yaw), np.sin(yaw), np.cos(-pitch), np.sin(-pitch), np.cos(roll),
                              np.sin(roll))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx @ _R_BASE


def clearance(scene: Scene, xy: np.ndarray, style: PathStyle) -> np.ndarray:
    """How far (m) a camera path may wander from each point (N, 2) before breaking a margin (< 0: inside)."""
    lo, hi = scene.room_lo[:2], scene.room_hi[:2]
    c = np.minimum(xy - lo, hi - xy).min(axis=1) - style.wall_margin
    for x0, y0, x1, y1 in scene.obstacles:
        dx = np.maximum(np.maximum(x0 - xy[:, 0], xy[:, 0] - x1), 0.0)
        dy = np.maximum(np.maximum(y0 - xy[:, 1], xy[:, 1] - y1), 0.0)
        inside = (dx == 0) & (dy == 0)
        d = np.where(inside, -1.0, np.hypot(dx, dy))
        c = np.minimum(c, d - style.obstacle_margin)
    return c


def free_spot(scene: Scene, rng: np.random.Generator, style: PathStyle, min_radius: float = 0.12):
    """A point with room for a loop of at least ``min_radius``: (xy (2,), available radius)."""
    lo, hi = scene.room_lo[:2], scene.room_hi[:2]
    cand = rng.uniform(lo, hi, size=(256, 2))
    clr = clearance(scene, cand, style)
    ok = np.flatnonzero(clr >= min_radius)
    if ok.size == 0:
        raise ValueError(f"scene {scene.name}: no free spot for the camera (best clearance {clr.max():.2f} "
                         f"m); the room is too cluttered for the path margins")
    i = ok[0]
    return cand[i], float(clr[i])


def _sines(rng: np.random.Generator, t: np.ndarray, amp: float, freq: tuple[float, float], n: int = 2):
    """Sum of ``n`` sinusoids with random frequencies/phases, total amplitude ``amp``."""
    out = np.zeros_like(t)
    for k in range(n):
        f = rng.uniform(*freq)
        out += amp / n * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) * (1.0 if k == 0 else 0.7)
    return out


def _min_turn_radius(loop: np.ndarray) -> float:
    """Smallest radius of curvature (m) of a densely sampled closed curve (N, 2)."""
    a, b = loop[:-2] - loop[1:-1], loop[2:] - loop[1:-1]
    c = loop[2:] - loop[:-2]
    cross = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    r = (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1) * np.linalg.norm(c, axis=1)
         / (2 * cross + 1e-15))
    return float(r.min())


def _loop(rng: np.random.Generator, radius: float, tries: int = 20) -> np.ndarray:
    """A smooth closed curve (4097, 2) around the origin reaching ``radius``: a few random harmonics,
    redrawn until it has no sharp turn (a cusp would stop the camera for a frame); an ellipse if
    every draw had one."""
    theta = np.linspace(0.0, 2 * np.pi, 4097)
    for _ in range(tries):
        loop = np.zeros((theta.size, 2))
        for k in (1, 2, 3):
            a = rng.uniform(0.2, 1.0) / k**2
            loop[:, 0] += a * np.cos(k * theta + rng.uniform(0, 2 * np.pi))
            loop[:, 1] += a * rng.uniform(0.5, 1.0) * np.sin(k * theta + rng.uniform(0, 2 * np.pi))
        loop -= loop.mean(axis=0)
        loop *= radius / np.linalg.norm(loop, axis=1).max()
        if _min_turn_radius(loop) >= 0.3 * radius:
            break
    else:
        loop = np.stack([radius * np.cos(theta), radius * rng.uniform(0.5, 1.0) * np.sin(theta)], axis=1)
    return loop[::-1].copy() if rng.random() < 0.5 else loop


def handheld_path(scene: Scene, n_frames: int, rng: np.random.Generator,
                  style: PathStyle = PathStyle()) -> tuple[np.ndarray, np.ndarray]:
    """Camera poses of one sequence: (world_T_cam (N, 4, 4) float64, times (N,) seconds from 0)."""
    centre, avail = free_spot(scene, rng, style)
    radius = min(avail, rng.uniform(*style.radius))
    loop = _loop(rng, radius)
    seg = np.linalg.norm(np.diff(loop, axis=0), axis=1)
    arclen = np.concatenate([[0.0], np.cumsum(seg)])
    total = arclen[-1]
    # speed profile integrated finely, sampled at the frames
    times = np.arange(n_frames) / style.fps
    fine = np.linspace(0.0, max(times[-1], 1e-6), max(2, 20 * n_frames))
    v0 = rng.uniform(*style.speed)
    wob_f, wob_p = rng.uniform(0.1, 0.4), rng.uniform(0, 2 * np.pi)
    v = v0 * (1 + style.speed_wobble * np.sin(2 * np.pi * wob_f * fine + wob_p))
    s_fine = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(fine))])
    s = (np.interp(times, fine, s_fine) + rng.uniform(0, total)) % total
    xy = np.stack([np.interp(s, arclen, loop[:, 0]), np.interp(s, arclen, loop[:, 1])], axis=1) + centre
    z0 = rng.uniform(*style.height)
    z = z0 + style.bob * np.sin(2 * np.pi * rng.uniform(0.6, 1.0) * times + rng.uniform(0, 2 * np.pi))
    pos = np.concatenate([xy, z[:, None]], axis=1)
    # orientation: track a point of interest, pan, pitch and roll oscillations, tremor
    lo, hi = scene.room_lo, scene.room_hi
    cands = rng.uniform(lo + 0.3, hi - 0.3, size=(64, 3))
    cands[:, 2] = rng.uniform(0.3, 1.4, size=64)
    far = np.linalg.norm(cands[:, :2] - centre, axis=1)
    target = cands[int(np.argmax(far >= min(2.0, 0.8 * far.max())))]
    yaw = np.arctan2(target[1] - pos[:, 1], target[0] - pos[:, 0])
    yaw = np.unwrap(yaw) + np.deg2rad(_sines(rng, times, rng.uniform(*style.pan_amp), style.pan_freq))
    pitch = np.deg2rad(rng.uniform(*style.pitch)
                       + _sines(rng, times, rng.uniform(*style.pitch_amp), (0.1, 0.5)))
    roll = np.deg2rad(rng.uniform(*style.roll) + _sines(rng, times, rng.uniform(*style.roll_amp), (0.1, 0.5)))
    for ang in (yaw, pitch, roll):
        ang += np.deg2rad(_sines(rng, times, style.tremor, (1.5, 4.0)))
    poses = np.tile(np.eye(4), (n_frames, 1, 1))
    for k in range(n_frames):
        poses[k, :3, :3] = rotation(yaw[k], pitch[k], roll[k])
        poses[k, :3, 3] = pos[k]
    return poses, times
