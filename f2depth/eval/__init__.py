"""Evaluation: the test sets behind one interface, depth metrics, timing.

Modules: ``registry`` (the test sets, one line each), ``protocol`` (:class:`~f2depth.eval.protocol.Protocol`:
how a test set opens and is scored), ``scoring`` (the one scoring recipe, its ``Settings`` and
``ProtocolResult``), ``inputs`` (network input, batches), ``nyu``, ``sevenscenes``, ``campus`` (their
protocols), ``suite`` (every test set for one model), ``metrics`` (per-image metrics, median scaling,
aggregation, flip post-processing) and ``timing``. The samples are ``f2depth.data.samples``; the tables,
their layouts and the paper's published numbers are ``f2depth.report``.
"""
