"""The FlyingChairs-style generator: its ground truth is exact (frame 2 warped by it is frame 1 wherever
nothing occludes), its occlusion and motion follow the layers, and a seed fixes every pair."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from f2depth.flow.chairs import ChairsSpec, Layer, flow_truth, render_frames, render_pairs, texture_pool
from f2depth.geometry import warp


def spec(**kw) -> ChairsSpec:
    base = {"height": 64, "width": 96, "max_shift": 8, "small_share": 0.25, "rotation_deg": 5, "scale": 0.05,
            "min_shapes": 1, "max_shapes": 4, "min_size": 0.12, "max_size": 0.4, "supersample": 2,
            "textures": 6, "image_crops": 2}
    return ChairsSpec(**(base | kw))


@pytest.fixture(scope="module")
def pool() -> torch.Tensor:
    rng = np.random.default_rng(0)
    image = (rng.random((40, 50, 3)) * 255).astype(np.uint8)
    return texture_pool(spec(), np.random.default_rng(1), [image])


def test_pool_holds_procedural_textures_and_crops_covering_the_image_and_margin(pool):
    assert pool.shape == (8, 3, 2 * (64 + 64), 2 * (96 + 64)) and pool.dtype == torch.float32
    assert float(pool.min()) >= 0 and float(pool.max()) <= 1
    assert all(float(t.std()) > 0.01 for t in pool)  # every texture has texture


def test_ground_truth_warps_frame_2_onto_frame_1_on_visible_pixels(pool):
    img1, img2, flow, occluded = render_pairs(spec(), pool, np.random.default_rng(2), 6)
    assert img1.shape == (6, 3, 64, 96) and flow.shape == (6, 2, 64, 96) and occluded.dtype == torch.bool
    visible = ~occluded
    err = (warp(img2, flow) - img1).abs().mean(1, keepdim=True)[visible]
    zero = (img2 - img1).abs().mean(1, keepdim=True)[visible]
    assert float(flow.norm(dim=1).mean()) > 2  # the pairs move
    assert 0.01 < float(occluded.float().mean()) < 0.4
    # bilinear interpolation and 8-bit steps are all that is left
    assert float(err.median()) < 0.01 and float(err.mean()) < 0.25 * float(zero.mean())
    # and a wrong flow does not fit: the same field shifted by one pixel
    off = (warp(img2, flow + torch.tensor([1.0, 0.0]).view(1, 2, 1, 1)) - img1).abs().mean(1, keepdim=True)
    assert float(off[visible].mean()) > 2 * float(err.mean())


def test_a_seed_fixes_every_pair(pool):
    a = render_pairs(spec(), pool, np.random.default_rng(5), 2)
    b = render_pairs(spec(), pool, np.random.default_rng(5), 2)
    c = render_pairs(spec(), pool, np.random.default_rng(6), 2)
    assert all(torch.equal(x, y) for x, y in zip(a, b))
    assert not torch.equal(a[2], c[2])


def test_flow_and_occlusion_follow_the_layers():
    s = spec(supersample=1)
    background = Layer(0, "background", (), (47.5, 31.5), 0.0, (0.0, 0.0), 0.0, 1.0)
    square = Layer(1, "rectangle", (10.0, 10.0), (40.0, 30.0), 0.0, (5.0, 0.0), 0.0, 1.0)
    flow, occluded = flow_truth(s, [background, square])
    assert torch.equal(flow[:, 30, 40], torch.tensor([5.0, 0.0]))  # inside the square
    assert torch.equal(flow[:, 5, 5], torch.tensor([0.0, 0.0]))    # static background
    assert bool(occluded[0, 30, 53]) and not bool(occluded[0, 30, 60])  # covered by the square in frame 2
    assert not bool(occluded[0, 30, 40]) and not bool(occluded[0, 5, 5])
    spin = Layer(1, "ellipse", (20.0, 15.0), (48.0, 32.0), 0.3, (0.0, 0.0), math.radians(4.0), 1.02)
    flow, _ = flow_truth(s, [background, spin])
    x, y = 58.0 - 48.0, 35.0 - 32.0   # a pixel inside, relative to the centre
    c, n = math.cos(math.radians(4.0)), math.sin(math.radians(4.0))
    expect = torch.tensor([1.02 * (c * x - n * y) - x, 1.02 * (n * x + c * y) - y])
    assert torch.allclose(flow[:, 35, 58], expect, atol=1e-4)


def test_frames_show_the_layer_order(pool):
    s = spec(supersample=1)
    background = Layer(0, "background", (), (47.5, 31.5), 0.0, (0.0, 0.0), 0.0, 1.0)
    disc = Layer(1, "ellipse", (12.0, 12.0), (48.0, 32.0), 0.0, (6.0, 0.0), 0.0, 1.0)
    frames = render_frames(s, pool, [[background, disc]])[0]
    # frame 1's disc centre shows texture 1, frame 2's disc has moved 6 px right, and the background
    # behind frame 1's left rim is visible again in frame 2
    assert torch.allclose(frames[0][:, 32, 48], frames[1][:, 32, 54], atol=2 / 255)
    only_bg = render_frames(s, pool, [[background]])[0]
    assert torch.allclose(frames[1][:, 32, 38], only_bg[1][:, 32, 38], atol=1e-6)
    assert not torch.allclose(frames[0][:, 32, 38], only_bg[0][:, 32, 38], atol=1e-3)


def test_the_topmost_layer_shows_and_each_pair_composes_only_its_own_layers(pool):
    s = spec(supersample=2)
    background = Layer(0, "background", (), (47.5, 31.5), 0.0, (0.0, 0.0), 0.0, 1.0)
    square = Layer(1, "rectangle", (14.0, 14.0), (44.0, 30.0), 0.2, (2.0, 1.0), 0.0, 1.0)
    disc = Layer(2, "ellipse", (8.0, 8.0), (48.0, 32.0), 0.0, (-3.0, 0.0), 0.05, 1.02)
    star = Layer(3, "star", (12.0, 6.0) * 5, (20.0, 20.0), 0.4, (1.0, -2.0), 0.0, 0.97)
    scenes = [[background, square, disc], [background, star]]
    both = render_frames(s, pool, scenes)
    alone = [render_frames(s, pool, [layers])[0] for layers in scenes]
    assert torch.equal(both[0], alone[0]) and torch.equal(both[1], alone[1])
    # where the disc covers the square, the disc (the later layer) is what frame 1 shows
    disc_only = render_frames(s, pool, [[background, disc]])[0]
    square_only = render_frames(s, pool, [[background, square]])[0]
    assert torch.equal(both[0, 0][:, 32, 48], disc_only[0][:, 32, 48])
    assert not torch.allclose(both[0, 0][:, 32, 48], square_only[0][:, 32, 48], atol=1e-3)
    assert torch.equal(both[0, 0][:, 20, 36], square_only[0][:, 20, 36])  # the square outside the disc


def test_frames_equal_every_layer_sampled_whole_and_composited_in_order(pool):
    """Sampling each position only in its topmost layer's texture gives, bit for bit, the plain painter's
    composite: every layer sampled over the whole frame, later layers pasted over earlier ones."""
    from f2depth.flow.chairs import _texture_theta, draw_layers, inside, layer_matrix

    s = spec(supersample=2)
    scenes = [draw_layers(s, np.random.default_rng([4, i]), len(pool)) for i in range(5)]
    got = render_frames(s, pool, scenes)
    h, w, k = s.height * 2, s.width * 2, 2
    texels = torch.tensor([pool.shape[-1], pool.shape[-2]])
    for p, layers in enumerate(scenes):
        for frame in (1, 2):
            theta = torch.from_numpy(np.stack([_texture_theta(layer_matrix(la, frame), (s.height, s.width),
                                                              tuple(pool.shape[-2:]), k)
                                               for la in layers])).float()
            grid = F.affine_grid(theta, [len(layers), 3, h, w], align_corners=False)
            whole = F.grid_sample(pool[[la.texture for la in layers]], grid, mode="bilinear",
                                  padding_mode="reflection", align_corners=False)
            painted = whole[0]
            for i, la in enumerate(layers[1:], 1):
                painted = torch.where(inside(la, grid[i] * texels / (2 * k)), whole[i], painted)
            want = (F.avg_pool2d(painted[None], k)[0].clamp(0, 1) * 255).round() / 255
            assert torch.equal(got[p, frame - 1], want), (p, frame)


def test_a_pair_without_its_background_first_is_refused(pool):
    disc = Layer(2, "ellipse", (8.0, 8.0), (48.0, 32.0), 0.0, (-3.0, 0.0), 0.05, 1.02)
    with pytest.raises(ValueError, match="background"):
        render_frames(spec(), pool, [[disc]])


def test_spec_rejects_inverted_ranges():
    with pytest.raises(ValueError, match="max_shapes"):
        spec(min_shapes=3, max_shapes=2)
    with pytest.raises(ValueError, match="max_size"):
        spec(min_size=0.5, max_size=0.2)
