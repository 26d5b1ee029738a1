"""Camera poses from multi-view geometry: the prior of ``train_depth.pose_prior: geometric``.

Not part of F²Depth or P²Net; after GasMono's coarse poses from structure from motion and MonoIndoor's
residual pose.

``tracks`` (KLT corner tracks) → ``reconstruct`` (incremental structure from motion, ``bundle`` adjustment)
→ ``estimate`` (per scene, the priors of the training pairs) → ``store`` (``data/poses``, docs/formats.md);
``metrics`` scores them against the synthetic ground truth.
"""
