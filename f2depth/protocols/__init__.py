"""The test sets' evaluation protocols and depth metrics (training validates with NYU's).

Modules: ``registry`` (the test sets, one line each), ``protocol``
(:class:`~f2depth.protocols.protocol.Protocol`: how a test set opens and is scored), ``scoring`` (the one
scoring recipe, its ``Settings`` and ``ProtocolResult``), ``inputs`` (network input, batches), ``nyu``,
``sevenscenes``, ``campus`` (their protocols) and ``metrics`` (per-image metrics, median scaling,
aggregation). The network's disparity with flip post-processing is ``f2depth.depth.predict``; the samples are
``f2depth.formats.samples``.
"""
