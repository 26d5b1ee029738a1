"""The flow-network interface: all that pretraining, fine-tuning, evaluation and the frozen teacher of depth
training use of a flow network. ARFlow's PWC-Lite (:class:`f2depth.flow.net.pwclite.PWCLite`) is the one the
paper uses; the registry that names the implementations is ``f2depth.flow.net.checkpoint.NETWORKS``, and the
checkpoint records the name, so a model file rebuilds its own network (docs/flow_finetune.md, "Swapping
the flow network").
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import torch
from torch import nn


class FlowNetwork(nn.Module, ABC):
    """A two-frame optical-flow network.

    ``flows_fw, flows_bw = net(img1, img2, with_backward=True)``: images ``(B,3,H,W)`` RGB in [0, 1] of
    any size (a network that needs other sizes resizes inside, as PWC-Lite does) → two lists of flows
    ``(B,2,h_i,w_i)``, finest first, level 0 at ``(H, W)``, each level in pixels of its own resolution, x
    first; ``flows_fw`` is frame 1 → frame 2, ``flows_bw`` frame 2 → frame 1 or None without
    ``with_backward``. The fine-tuning and pretraining losses weigh the levels with ``w_scales`` (finest
    first; a one-level network needs ``flow_finetune.w_scales: [1]``).

    ``features(img)``: the feature pyramid that L_feature compares (the paper §3.3), any number of
    levels ``(B,C_l,h_l,w_l)``, computed on ``img (B,3,H,W)`` as given.

    ``architecture()``: the constructor's keyword arguments that fix the weights' shapes; the checkpoint
    records them and passes them back when it rebuilds the network.

    ``feature_module()`` and ``flow_heads()``: what the supervised bootstrap (f2depth.flow.bootstrap)
    trains first and zeroes; the defaults (the whole network, none) work for any network.
    """

    @abstractmethod
    def forward(self, img1: torch.Tensor, img2: torch.Tensor, with_backward: bool = True
                ) -> tuple[list[torch.Tensor], list[torch.Tensor] | None]: ...

    @abstractmethod
    def features(self, img: torch.Tensor) -> list[torch.Tensor]: ...

    def architecture(self) -> dict[str, Any]:
        return {}

    def flow_levels(self) -> int:
        """How many flows ``forward`` returns per direction (what ``w_scales`` may weigh). Default: counted on
        one forward pass of a 64×64 pair."""
        probe = torch.zeros(1, 3, 64, 64, device=next(self.parameters()).device)
        with torch.no_grad():
            return len(self(probe, probe, with_backward=False)[0])

    def feature_module(self) -> nn.Module:
        """The submodule that computes :meth:`features` (what the chairs bootstrap's phase A trains alone;
        f2depth.flow.bootstrap). Default: the whole network."""
        return self

    def flow_heads(self) -> list[nn.Conv2d]:
        """The convolutions whose outputs are added to the flow (zeroed by the chairs bootstrap, so the
        first output is zero flow). Default: none."""
        return []


def msra_init(model: nn.Module, generator: torch.Generator | None = None) -> nn.Module:
    """MSRA initialisation of every convolution (Kaiming normal, fan-in, zero bias), in place.

    This is what ARFlow's ``init_weights`` sets out to do; because that method tests the (name, module)
    tuples of ``named_modules()`` against ``nn.Conv2d`` it never matches, so ARFlow actually trains from
    PyTorch's default initialisation (ARFlow's code, ``models/pwclite.py``). Default-initialised
    features are small and the cost volume (a mean of products) is then ~100× smaller than the decoder's
    other inputs.
    """
    with torch.no_grad():
        for module in model.modules():
            if isinstance(module, nn.Conv2d):
                fan_in = module.in_channels // module.groups * module.kernel_size[0] * module.kernel_size[1]
                std = (2.0 / fan_in) ** 0.5
                module.weight.copy_(torch.randn(module.weight.shape, generator=generator) * std)
                if module.bias is not None:
                    module.bias.zero_()
    return model


def make_optimizer(model: nn.Module, cfg: Any) -> torch.optim.Optimizer:
    """ARFlow's Adam for pretraining and fine-tuning: betas (0.9, 0.999), eps 1e-7, constant ``cfg.lr``,
    weight decay ``cfg.weight_decay`` on weights and none on biases (ARFlow's ``bias_decay`` 0)."""
    weights = [p for n, p in model.named_parameters() if not n.endswith("bias")]
    biases = [p for n, p in model.named_parameters() if n.endswith("bias")]
    groups = [{"params": weights, "weight_decay": cfg.weight_decay}, {"params": biases, "weight_decay": 0.0}]
    return torch.optim.Adam(groups, lr=cfg.lr, betas=(0.9, 0.999), eps=1e-7)
