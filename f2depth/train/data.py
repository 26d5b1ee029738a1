"""The depth-training dataset: one item per prepared frame tuple (target 0, sources −1 / +1).

An item is a dict of tensors (collated by the default DataLoader collate):

* ``target``, ``prev``, ``next`` (3,H,W) float32 RGB in [0, 1] — un-augmented (flipped if the sample is
  flipped): they feed the losses and the frozen flow network;
* ``target_aug``, ``prev_aug``, ``next_aug`` (3,H,W) — colour-jittered copies: they feed the depth and
  pose networks (P²Net's `datasets/nyu_dataset.py`);
* ``points`` (N,2) int64 x first — the target's DSO keypoints, filled up with uniform random pixels to
  ``num_points`` (P²Net §3.2); ``points_real`` (N,) bool marks the keypoints;
* ``segments`` (H,W) int64 Felzenszwalb labels; ``K`` (3,3) float32 (mirrored with the sample);
* ``index`` int64, ``flipped`` bool;
* with pose priors (``train_depth.pose_prior: geometric``): ``prior_prev``, ``prior_next`` (4,4) float32 —
  ``prev_T_target`` and ``next_T_target`` from multi-view geometry (``f2depth.poses``), mirrored with the
  sample; the identity where the pair has no reliable prior — and ``prior_prev_ok``, ``prior_next_ok`` bool.

Reproducibility: the augmentation and the fill-up points of item ``i`` in epoch ``e`` are drawn from
generators seeded with ``(seed, e, i)`` only (:func:`f2depth.epochs.sample_generator`), so they do not
depend on worker processes, on the order items are read in, or on whether a run was interrupted and
resumed.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
from torch.utils.data import Dataset

from f2depth.colour import P2NET_AUGMENT, AugmentConfig
from f2depth.epochs import sample_generator
from f2depth.formats.images import to_tensor
from f2depth.formats.prepared import VAL_TUPLES, PreparedSet
from f2depth.keypoints import KeypointFile, fill_up
from f2depth.poses.store import PosePriors
from f2depth.train import augment as A

#: Streams derived from (seed, epoch, index): augmentation, fill-up points and the epoch's order are
#: independent.
STREAM_AUGMENT = 0
STREAM_POINTS = 1
STREAM_ORDER = 2


@dataclass(frozen=True)
class DataConfig:
    num_points: int = 3000
    augment: bool = True
    augment_config: AugmentConfig = P2NET_AUGMENT


class TupleDataset(Dataset):
    """Prepared tuples + keypoints as training items (module docstring). ``item(index, epoch)`` is the
    primary accessor; ``ds[i]`` is ``item(i, epoch=0)``."""

    def __init__(self, prepared: PreparedSet | str | os.PathLike, keypoints: KeypointFile | str | os.PathLike,
                 config: DataConfig, seed: int = 0, priors: PosePriors | None = None,
                 held_out: bool = False) -> None:
        self.prepared = prepared if isinstance(prepared, PreparedSet) else PreparedSet(prepared)
        self.keypoints = keypoints if isinstance(keypoints, KeypointFile) else KeypointFile(keypoints)
        #: the training tuples, or with ``held_out`` the validation ones (val_tuples.csv, prepare.val_share)
        self.tuples = self.prepared.val_tuples if held_out else self.prepared.tuples
        if not self.tuples:
            raise ValueError(f"{self.prepared.root / (VAL_TUPLES if held_out else 'tuples.csv')}: no "
                             f"{'held-out' if held_out else 'training'} tuples; check prepare's scene "
                             "selection and prepare.val_share (a scene needs at least 3 sampled frames)")
        if config.num_points < 1:
            raise ValueError(f"train_depth.num_points must be >= 1, got {config.num_points}")
        self.config = config
        self.seed = int(seed)
        self.height, self.width = self.prepared.hw
        self.K = torch.from_numpy(self.prepared.K).float()
        missing = [t.target for t in self.tuples
                   if self.prepared.frame_index(t.target) not in self.keypoints]
        if missing:
            raise ValueError(f"{self.keypoints.path}: no keypoints for {len(missing)} target frames (first: "
                             f"{missing[0]}); the file does not belong to {self.prepared.root}: re-run "
                             "`dvc repro keypoints`")
        self.keypoints.check_inside(self.height, self.width)  # never clamp stray points silently
        if priors is not None:
            priors.check_covers([t.tuple_id for t in self.tuples])
        self.priors = priors

    def __len__(self) -> int:
        return len(self.tuples)

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        return self.item(index, 0)

    def item(self, index: int, epoch: int) -> dict[str, torch.Tensor]:
        t = self.tuples[index]
        frames = [to_tensor(self.prepared.image(fid)) for fid in (t.target, t.prev, t.next)]
        kp = self.keypoints.tensor(self.prepared.frame_index(t.target))
        segments = torch.from_numpy(self.prepared.segments(t.tuple_id))
        K = self.K.clone()
        d = A.draw(self.config.augment_config, sample_generator(self.seed, epoch, index, STREAM_AUGMENT))
        flipped = self.config.augment and d.flip
        if flipped:
            frames = [A.flip_image(f) for f in frames]
            segments = A.flip_image(segments)
            kp = A.flip_points(kp, self.width)
            K = A.flip_intrinsics(K, self.width)
        stacked = torch.stack(frames)
        aug = A.color_jitter(stacked, d) if self.config.augment else stacked
        points, real = fill_up(kp[:, :2], self.config.num_points, self.height, self.width,
                               sample_generator(self.seed, epoch, index, STREAM_POINTS))
        return {
            "target": frames[0], "prev": frames[1], "next": frames[2],
            "target_aug": aug[0], "prev_aug": aug[1], "next_aug": aug[2],
            "points": points, "points_real": real,
            "segments": segments.contiguous(), "K": K,
            "index": torch.tensor(index, dtype=torch.int64), "flipped": torch.tensor(flipped),
            **self._prior(t.tuple_id, flipped),
        }  # fmt: skip

    def _prior(self, tuple_id: str, flipped: bool) -> dict[str, torch.Tensor]:
        if self.priors is None:
            return {}
        p = self.priors[tuple_id]
        T_prev, T_next = torch.from_numpy(p.T_prev), torch.from_numpy(p.T_next)
        if flipped:
            T_prev, T_next = A.flip_pose(T_prev), A.flip_pose(T_next)
        return {"prior_prev": T_prev, "prior_next": T_next, "prior_prev_ok": torch.tensor(p.prev_ok),
                "prior_next_ok": torch.tensor(p.next_ok)}


class EpochView(Dataset):
    """The items ``indices`` of ``dataset`` as drawn for ``epoch`` (what a DataLoader iterates)."""

    def __init__(self, dataset: TupleDataset, epoch: int, indices: list[int]) -> None:
        self.dataset, self.epoch, self.indices = dataset, int(epoch), list(indices)

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, j: int) -> dict[str, torch.Tensor]:
        return self.dataset.item(self.indices[j], self.epoch)


def epoch_order(n: int, seed: int, epoch: int) -> list[int]:
    """The shuffled order of ``n`` items in ``epoch``: a function of (seed, epoch) only."""
    g = sample_generator(seed, epoch, 0, STREAM_ORDER)
    return [int(i) for i in torch.randperm(n, generator=g)]


def batch_problem(n: int, global_batch: int, world: int = 1) -> tuple[str, str] | None:
    """``(problem, fix)`` when whole global batches of ``global_batch`` items cannot be drawn from ``n``
    items and dealt to ``world`` processes; None when they can."""
    if global_batch < 1 or global_batch % world:
        return (f"train_depth.batch_size {global_batch} does not divide among the {world} processes of this "
                "run (a global batch must be a positive multiple of the world size)",
                f"set train_depth.batch_size to a multiple of {world} (each process reads batch_size / "
                "processes items)")
    if n < global_batch:
        return (f"{n} training tuples are fewer than one batch of train_depth.batch_size {global_batch}",
                "lower train_depth.batch_size or prepare more frames")
    return None


def rank_indices(n: int, seed: int, epoch: int, global_batch: int, rank: int = 0,
                 world: int = 1) -> list[int]:
    """Indices rank ``rank`` of ``world`` reads in ``epoch``, in order (DistributedSampler-like).

    The epoch's order is cut to whole global batches (``drop_last``, as P²Net) and dealt round-robin,
    so the union of the ranks' k-th local batches is exactly the k-th global batch of a one-process run.
    """
    if problem := batch_problem(n, global_batch, world):
        raise ValueError("; ".join(problem))
    order = epoch_order(n, seed, epoch)
    usable = (n // global_batch) * global_batch
    return order[:usable][rank::world]
