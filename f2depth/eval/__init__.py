"""Evaluation: the test sets behind one interface, depth metrics, timing, tables, published numbers.

Modules: ``registry`` (the test sets, one line each), ``protocol`` (:class:`~f2depth.eval.protocol.Protocol`:
how a test set opens, is scored and reported), ``scoring`` (the one scoring recipe, its ``Settings`` and
``ProtocolResult``), ``inputs`` (:class:`~f2depth.eval.inputs.EvalSample`, the typed sample every loader
returns; subsets, network input, batches), ``nyu``, ``sevenscenes``, ``campus`` (their protocols),
``suite`` (every test set for one model), ``metrics`` (per-image metrics, median scaling, aggregation, flip
post-processing), ``timing``, ``tables`` (Markdown / CSV / LaTeX) and ``published`` (the paper's numbers).
"""
