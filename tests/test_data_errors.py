"""Tests for f2depth.errors: message format and survival across process boundaries."""

from __future__ import annotations

import pickle

from f2depth.errors import DataError


def test_message_names_path_problem_and_fix():
    e = DataError("data/x.csv", "row 3: depth_m = -1 is not positive", "depths are metres > 0")
    assert str(e) == "data/x.csv: row 3: depth_m = -1 is not positive; depths are metres > 0"
    assert isinstance(e, ValueError)
    assert (e.path, e.fix) == ("data/x.csv", "depths are metres > 0")
    assert e.problem == "row 3: depth_m = -1 is not positive"


def test_without_fix_and_ready_message():
    assert str(DataError("a.png", "empty file")) == "a.png: empty file"
    assert str(DataError("a.png: already formatted")) == "a.png: already formatted"


def test_pickles_with_its_message():  # raised in prepare's worker processes
    e = pickle.loads(pickle.dumps(DataError("a.png", "truncated", "re-copy it")))
    assert isinstance(e, DataError) and str(e) == "a.png: truncated; re-copy it"
