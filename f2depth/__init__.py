"""F²Depth: self-supervised indoor monocular depth supervised by a patch-loss fine-tuned flow network."""

__version__ = "0.1.0"
