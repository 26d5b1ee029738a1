"""The synthetic indoor world: a deterministic generator of indoor video and images in the on-disk formats
of NYU Depth V2 (raw and labeled), 7-Scenes, Campus and MPI Sintel, with exact ground truth
(docs/formats.md).

Modules: ``textures`` (procedural albedo), ``styles`` and ``layout`` (rooms and furniture),
``scene`` (boxes, lights, baked radiance atlas), ``camera_path`` (handheld motion), ``render`` (ray
casting), ``sensor`` (exposure, vignetting, noise), ``groundtruth`` (flow, occlusion, Kinect holes),
``writers`` and ``matfiles`` (file formats), ``plan`` and ``jobs`` (what to generate, one job per
sequence), ``world`` (:func:`generate`, the entry point). The names below are imported from their
module on first use, so importing one module of this package loads no other.
"""

from f2depth.lazy import lazy_getattr

_HOMES = {"OutputPaths": "config", "SynthConfig": "config", "generate": "world", "FINISH": "world",
          "MANIFEST_VERSION": "world"}
__all__ = sorted(_HOMES)

__getattr__ = lazy_getattr(__name__, _HOMES)
