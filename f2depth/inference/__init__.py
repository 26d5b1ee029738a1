"""Using a trained depth network: ``f2depth predict`` (images, folders, video → depth files),
``f2depth export`` (ONNX) and ``f2depth reconstruct`` (TSDF fusion of a posed sequence).

Modules: ``backends`` (PyTorch checkpoint or onnxruntime), ``predict``
(resize, predict, post-process, scale, write), ``outputs`` (file formats), ``scaling`` (median scaling),
``export`` (ONNX + parity), ``sequences`` (posed sequences), ``reconstruct`` (TSDF fusion and mesh
metrics), ``optional`` (lazy optional imports). The input frames come from ``f2depth.ingest.sources``; the
command line lives in ``f2depth.cli``.
"""
