"""``f2depth ingest``: a user's videos and image folders → a raw frame folder the pipeline trains on
(docs/ingest.md).

Modules: ``sources`` (where frames come from: an image, a folder of images or a video; ``f2depth predict``
reads them too), ``camera_files`` and ``selfcal`` (the camera), ``select`` (which frames to keep) and
``run`` (the whole ingest)."""
