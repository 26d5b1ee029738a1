"""The flow network the frozen teacher of depth training needs, apart from the flow training routes:
``network`` (the :class:`~f2depth.flow.net.network.FlowNetwork` interface), ``pwclite`` (ARFlow's PWC-Lite),
``correlation`` (its cost volume) and ``checkpoint`` (the registry of networks, their checkpoints and
ARFlow's released ones)."""
