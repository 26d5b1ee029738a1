"""The ``evaluate`` stage: every test-set protocol (``f2depth.protocols``) over a trained model, and timing.

Modules: ``suite`` (every test set for one model) and ``timing``. The tables, their layouts and the paper's
published numbers are ``f2depth.report``.
"""
