"""The paper's tables and figures from the evaluation results.

Modules: ``results`` (reading metrics/evaluate, reports/eval and the flow metrics), ``paper_tables`` (rows
and columns of Table 1, 5, 6, the 7-Scenes and Campus per-scene tables, inference time; written with
``f2depth.eval.tables``) and ``figures`` (qualitative grids, error maps, training curves).
"""
