"""Loaders of the on-disk datasets (``docs/formats.md``) and the ``prepare`` stage.

Every loader validates what it reads and raises :class:`f2depth.data.errors.DataError` naming the
file, the problem and the fix; nothing is skipped silently.
"""
