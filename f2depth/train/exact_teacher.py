"""A diagnosis, not the method: the frozen teacher with its flow replaced by the exact rigid flow.

``train_depth.teacher: exact`` (the synthetic default only). Each training pair's flow target → source is
computed from the synthetic world's ground truth, ``rigid_flow(D_t, K, src_T_tgt)`` with the true depth of
the target and the true relative pose, instead of the flow network's estimate; the feature pyramids
(L_feature) stay the frozen network's. Where the target has no valid ground-truth depth the network's flow
is kept.

It answers one question: do F²Depth's terms help when their flow is right? With the exact flow L_rigid lifts
depth on every test set of the CPU default (docs/method.md §6), so what a trained teacher costs is its own
error. Frames are matched to their ground truth by the bytes of the image the teacher is given (the
un-augmented frame, flipped or not, exactly as ``TupleDataset`` builds it); a flipped pair's flow is the
mirror of the unflipped pair's (u negated).
"""

from __future__ import annotations

import hashlib

import torch

from f2depth.errors import DataError
from f2depth.flow import FlowNetwork, load_flow_model
from f2depth.formats.images import to_tensor
from f2depth.formats.prepared import PreparedSet
from f2depth.geometry import relative_pose, rigid_flow
from f2depth.train.augment import flip_image
from f2depth.train.teacher import FlowTeacher, TeacherOutput


def image_key(img: torch.Tensor) -> bytes:
    """A digest of one frame (3,H,W) float32 as the teacher receives it."""
    return hashlib.blake2b(img.detach().contiguous().cpu().float().numpy().tobytes(), digest_size=16).digest()


class ExactTeacher(FlowTeacher):
    """``FlowTeacher`` whose flow is the ground-truth rigid flow (module docstring).

    ``truth``: image key → (frame id, flipped); ``depth``: frame id → (1,H,W) metres (0 = invalid);
    ``world_T_cam``: frame id → (4,4); ``K`` (3,3) of the unflipped frames.
    """

    def __init__(self, net: FlowNetwork, truth: dict[bytes, tuple[str, bool]], depth: dict[str, torch.Tensor],
                 world_T_cam: dict[str, torch.Tensor], K: torch.Tensor, device: str | torch.device = "cpu",
                 memo_mb: float = 0.0) -> None:
        super().__init__(net, device, memo_mb)
        self.truth, self.depth, self.world_T_cam, self.K = truth, depth, world_T_cam, K.double()

    @classmethod
    def from_prepared(cls, flow_model: str, prepared: PreparedSet, device: str | torch.device = "cpu",
                      memo_mb: float = 0.0) -> ExactTeacher:
        """The network of ``flow_model`` and the ground truth of every training frame of ``prepared``;
        a frame without ground truth is an error (real data has none)."""
        frames = sorted({f for t in prepared.tuples for f in (t.target, t.prev, t.next)})
        truth: dict[bytes, tuple[str, bool]] = {}
        depth: dict[str, torch.Tensor] = {}
        poses: dict[str, torch.Tensor] = {}
        for fid in frames:
            gt = prepared.gt(fid)
            if gt is None:
                raise DataError(prepared.root / "frames.csv", f"frame {fid} has no ground truth: "
                                "train_depth.teacher: exact needs the synthetic world's depth and poses",
                                "set train_depth.teacher: network (exact is a diagnosis of the synthetic "
                                "default)")
            img = to_tensor(prepared.image(fid))
            truth[image_key(img)] = (fid, False)
            truth[image_key(flip_image(img))] = (fid, True)
            depth[fid] = torch.from_numpy(gt[0])[None].double()
            poses[fid] = torch.from_numpy(gt[1])
        K = torch.from_numpy(prepared.K).double()
        return cls(load_flow_model(flow_model), truth, depth, poses, K, device, memo_mb)

    def exact_flow(self, target: torch.Tensor, source: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """target, source (B,3,H,W) → the exact flow (B,2,H,W) pixels, x first, float32, and where it is
        valid (B,1,H,W) bool. A frame that is not a training frame is an error."""
        flows, valid = [], []
        for tgt_img, src_img in zip(target, source):
            (tgt, flipped), (src, src_flipped) = (self._match(x) for x in (tgt_img, src_img))
            if flipped != src_flipped:
                raise ValueError(f"pair {tgt} → {src}: one frame flipped, the other not")
            d = self.depth[tgt]
            T = relative_pose(self.world_T_cam[tgt], self.world_T_cam[src])  # src_T_tgt
            flow = rigid_flow(d[None], self.K[None], T[None])[0]
            ok = d > 0
            if flipped:
                flow, ok = torch.flip(flow, dims=(-1,)), torch.flip(ok, dims=(-1,))
                flow = torch.stack((-flow[0], flow[1]))
            flows.append(flow.float())
            valid.append(ok)
        return torch.stack(flows).to(target.device), torch.stack(valid).to(target.device)

    def _match(self, img: torch.Tensor) -> tuple[str, bool]:
        key = image_key(img)
        if key not in self.truth:
            raise ValueError("train_depth.teacher: exact was given a frame that is no training frame of the "
                             "prepared set (only the un-augmented training frames have ground truth)")
        return self.truth[key]

    def _run(self, target: torch.Tensor, source: torch.Tensor, features: bool) -> TeacherOutput:
        out = super()._run(target, source, features)
        with torch.autocast(target.device.type, enabled=False):
            exact, valid = self.exact_flow(target.float(), source.float())
        return TeacherOutput(torch.where(valid, exact, out.flow), out.feats_tgt, out.feats_src, out.valid)
