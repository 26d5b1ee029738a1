"""DepthCNN + PoseCNN (Monodepth2 / P²Net architecture) with torchvision-compatible ResNet encoders;
``predict`` runs a depth network for evaluation (disparity at a size, flip post-processing). The names below
are imported from their module on first use, so importing one module of this package loads no other."""

from f2depth.lazy import lazy_getattr

_HOMES = {"disp_to_depth": "decoder", "DepthModel": "model", "DepthModelConfig": "model",
          "load_checkpoint": "model", "model_from_checkpoint": "model", "read_checkpoint": "model",
          "save_checkpoint": "model"}
__all__ = sorted(_HOMES)

__getattr__ = lazy_getattr(__name__, _HOMES)
