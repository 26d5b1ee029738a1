"""The ``prepare`` stage: ``prepare`` (NYU raw video or an ingested one → the prepared training set) and
``training_video`` (which raw video that is: ``train_source`` of params.yaml). The formats it reads and
writes are ``f2depth.formats``.
"""
