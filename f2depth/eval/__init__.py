"""Evaluation: depth metrics, the NYU / 7-Scenes / Campus protocols, timing, tables, published numbers.

Modules: ``metrics`` (per-image metrics, median scaling, aggregation, flip post-processing),
``inputs`` (sample fields, input resizing, batched prediction), ``nyu``, ``sevenscenes``, ``campus``
(protocols taking an iterable of samples and a ``predict_disp`` callable), ``timing``, ``tables``
(Markdown / CSV / LaTeX) and ``published`` (the paper's numbers).
"""
