"""A resumed run never trains on changed inputs (issue 25, item 1). Before: the resume fingerprint covered
the settings, the pair lists, tuples.csv, camera.json, keypoints and model files but not the images or the
superpixels, so kill -9 after epoch 1, a re-run of `prepare` with `interpolation: area` (or
`superpixels.scale: 300`) and a re-run of `train_depth` reported `resumed_from: 1`: a model trained half on
old data. Now the fingerprint covers the prepared set's contents and the restart says what changed."""

from __future__ import annotations

import contextlib
import logging

import cv2
import numpy as np
import pytest
import torch
import train_fakes

from f2depth import params as P
from f2depth import tracking
from f2depth.epochs import fingerprint, load_state, save_state
from f2depth.train.run import resume_states, run_fingerprints, train_variant
from f2depth.train.settings import settings_from_params


class Interrupt(Exception):
    """Stands in for kill -9 after the first epoch's state is saved."""


class StopAfterFirstEpoch(tracking.StageRun):
    def log_metrics(self, metrics, step=None):
        if step == 1:
            raise Interrupt


@pytest.fixture
def setup(tmp_path):
    torch.set_num_threads(1)
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=6)
    mat, splits = train_fakes.write_nyu_test(tmp_path, n=2)
    path = train_fakes.write_params(tmp_path, prep, mat, splits, None, epochs=2, seeds=[0])
    return tmp_path, prep, settings_from_params(P.load(path), "baseline")


def interrupted_then_rerun(tmp_path, s, edit, caplog):
    with pytest.raises(Interrupt):
        train_variant(s, tmp_path / "build1", progress=False,
                      open_run=lambda seed: contextlib.nullcontext(StopAfterFirstEpoch()))
    assert load_state(resume_states(s)[0], run_fingerprints(s)[0])[0]["epoch"] == 1  # resumable as it is
    edit()
    with caplog.at_level(logging.WARNING):
        run = train_variant(s, tmp_path / "build2", progress=False)
    return run.metrics["per_seed"][0]["resumed_from_epoch"], caplog.text


def test_changed_images_restart_the_run_saying_why(setup, caplog):
    tmp_path, prep, s = setup

    def reinterpolate():  # what `prepare` with another interpolation does: same files, other pixels
        for image in sorted((prep / "images").rglob("*.png")):
            rgb = cv2.imread(str(image))
            cv2.imwrite(str(image), cv2.GaussianBlur(rgb, (3, 3), 0))

    resumed, log = interrupted_then_rerun(tmp_path, s, reinterpolate, caplog)
    assert resumed == 0
    assert "belongs to a run with other settings or inputs (input prepared changed); starting afresh" in log


def test_changed_superpixels_restart_the_run(setup, caplog):
    tmp_path, prep, s = setup

    def resegment():  # `superpixels.scale: 300`: other segments, same tables
        for seg in sorted((prep / "segments").glob("*.png")):
            cv2.imwrite(str(seg), (cv2.imread(str(seg), cv2.IMREAD_UNCHANGED) // 2).astype(np.uint16))

    resumed, log = interrupted_then_rerun(tmp_path, s, resegment, caplog)
    assert resumed == 0 and "(input prepared changed)" in log


def test_unchanged_inputs_still_resume(setup, caplog):
    tmp_path, _, s = setup
    resumed, _ = interrupted_then_rerun(tmp_path, s, lambda: None, caplog)
    assert resumed == 1


def test_a_mismatch_names_every_part_that_changed(tmp_path):
    (tmp_path / "a.bin").write_bytes(b"one")
    old = fingerprint({"lr": 1e-4, "epochs": 3}, {"images": tmp_path / "a.bin"})
    save_state(tmp_path / "s.pt", run="r", fingerprint=old, epoch=1, history=[], parts={})
    (tmp_path / "a.bin").write_bytes(b"two")
    new = fingerprint({"lr": 1e-5, "epochs": 3}, {"images": tmp_path / "a.bin"})
    state, note = load_state(tmp_path / "s.pt", new)
    assert state is None
    assert note.endswith("belongs to a run with other settings or inputs (input images, setting lr changed); "
                         "starting afresh")
    assert load_state(tmp_path / "s.pt", old)[0]["epoch"] == 1
