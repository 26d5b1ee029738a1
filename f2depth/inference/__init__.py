"""Using a trained depth network: ``f2depth predict`` (images, folders, video → depth files),
``f2depth export`` (ONNX) and ``f2depth reconstruct`` (TSDF fusion of a posed sequence).

Modules: ``sources`` (input frames), ``backends`` (PyTorch checkpoint or onnxruntime), ``predict``
(resize, predict, post-process, scale, write), ``outputs`` (file formats), ``scaling`` (median scaling),
``export`` (ONNX + parity), ``sequences`` (posed sequences), ``reconstruct`` (TSDF fusion and mesh
metrics), ``optional`` (lazy optional imports). The command line lives in ``f2depth.cli``.
"""
