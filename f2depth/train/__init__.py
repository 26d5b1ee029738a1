"""Depth training (DepthCNN + PoseCNN, the paper §3.2–3.4): data, frozen flow teacher, one step, lr schedule,
the epoch loop with checkpoints and resume, DDP helpers, per-epoch validation, and the per-variant runner.

Modules: ``augment`` (flip, colour jitter), ``data`` (TupleDataset, seeded order), ``teacher``
(FlowTeacher), ``step`` (losses of one batch, train_step), ``schedule`` (LRSchedule), ``loop`` (fit, on
the skeleton every trainer shares, f2depth.epochs: resume, history.csv, non-finite policy),
``distributed`` (torchrun/DDP), ``validate`` (δ1, AbsRel per epoch), ``settings`` (variant from
params.yaml), ``run`` (train_variant: all seeds, outputs).
"""
