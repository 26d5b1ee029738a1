"""``f2depth ingest``: a user's videos and image folders → a raw frame folder the pipeline trains on
(docs/ingest.md)."""
