"""The on-disk formats (``docs/formats.md``): every dataset's reader (and writer where the pipeline writes
one) and the prepared training set.

Modules: ``images`` (image files, validated), ``nyu_raw`` (NYU's raw video, or an ingested one),
``nyu_labeled``, ``sevenscenes``, ``campus`` (the test sets), ``samples`` (the typed sample every test-set
reader returns), ``sintel`` (MPI-Sintel layout, ``.flo``), ``prepared`` (the prepared set and how a raw
frame becomes one of its images) and ``writable`` (output locations checked before any work).

Every reader validates what it reads and raises :class:`f2depth.errors.DataError` naming the file, the
problem and the fix; nothing is skipped silently.
"""
