"""The paper's tables and figures from the evaluation results.

Modules: ``results`` (reading metrics/evaluate, reports/eval and the flow metrics), ``paper_tables`` (rows
and columns of Table 1, 5, 6, the 7-Scenes and Campus per-scene tables, inference time), ``tables``
(Markdown / CSV / LaTeX), ``layouts`` (how each test set shows in the tables), ``published`` (the paper's
numbers), ``build`` (the report's files) and ``figures`` (qualitative grids, error maps, training curves).
Only the `tables` stage imports this package.
"""
