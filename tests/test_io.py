"""Atomic writers: the destination appears whole or not at all, with ordinary permissions."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest

from f2depth import io


def test_write_json_converts_numpy_and_is_readable_by_others(tmp_path):
    path = tmp_path / "sub" / "m.json"
    io.write_json(path, {"a": np.float32(1.5), "b": np.arange(3), "c": tmp_path})
    assert json.loads(path.read_text()) == {"a": 1.5, "b": [0, 1, 2], "c": str(tmp_path)}
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_failed_write_leaves_old_file_and_no_temporaries(tmp_path):
    path = tmp_path / "x.txt"
    io.write_text(path, "old")
    with pytest.raises(RuntimeError), io.atomic_path(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("crash")
    assert path.read_text() == "old"
    assert os.listdir(tmp_path) == ["x.txt"]


def test_imwrite_and_npz_round_trip(tmp_path):
    img = np.random.default_rng(0).integers(0, 255, (5, 7, 3), dtype=np.uint8)
    io.imwrite(tmp_path / "a.png", img)
    import cv2

    assert np.array_equal(cv2.imread(str(tmp_path / "a.png")), img)
    io.save_npz(tmp_path / "a.npz", depth=img[..., 0].astype(np.float32))
    assert np.array_equal(np.load(tmp_path / "a.npz")["depth"], img[..., 0])
    with pytest.raises(OSError, match="could not write"):
        io.imwrite(tmp_path / "a.unknownext", img)


# ---- issue 53 item 1: a swapped-in folder replaces only its own kind ------------------------------------


def test_atomic_dir_replaces_only_an_empty_folder_or_its_own_output(tmp_path):
    """Before: atomic_dir replaced whatever folder it was given (a user's thesis folder included). Now it
    writes a marker into every folder it swaps in and refuses, before writing anything, a non-empty folder
    without its kind's marker."""
    out = tmp_path / "out"
    with io.atomic_dir(out, "predict") as tmp:
        (tmp / "a.txt").write_text("1")
    assert (out / io.OUTPUT_MARKER).read_text() == "predict\n" and io.output_kind(out) == "predict"
    with io.atomic_dir(out, "predict") as tmp:  # its own earlier output: replaced
        (tmp / "b.txt").write_text("2")
    assert sorted(p.name for p in out.iterdir()) == [io.OUTPUT_MARKER, "b.txt"]

    thesis = tmp_path / "thesis"
    thesis.mkdir()
    (thesis / "thesis.tex").write_text("four years")
    with pytest.raises(FileExistsError) as info, io.atomic_dir(thesis, "ingest", option="--out"):
        raise AssertionError("never entered")
    assert f"{info.value.filename}: {info.value.strerror}" == (
        f"{thesis}: holds files that f2depth ingest did not write (no .f2depth-output marker), and this run "
        "would replace the whole folder; give --out a new or empty folder (nothing was changed)")
    with pytest.raises(FileExistsError, match="holds the output of f2depth predict, not of ingest"), \
            io.atomic_dir(out, "ingest"):
        pass
    assert (thesis / "thesis.tex").read_text() == "four years"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "thesis"]  # no temporaries

    (tmp_path / "empty").mkdir()
    with io.atomic_dir(tmp_path / "empty", "ingest") as tmp:  # an empty folder is fine (mkdir first)
        (tmp / "c.txt").write_text("3")
    earlier = tmp_path / "earlier"  # an output written before the marker existed, recognised by its names
    earlier.mkdir()
    (earlier / "x_depth.npy").write_text("old")
    with io.atomic_dir(earlier, "predict", previous=lambda p: all(e.name.endswith(".npy")
                                                                  for e in p.iterdir())):
        pass
    assert sorted(p.name for p in earlier.iterdir()) == [io.OUTPUT_MARKER]
    with io.atomic_dir(thesis, "prepare", owned=True) as tmp:  # a DVC stage's output: DVC owns the path
        (tmp / "d.txt").write_text("4")
    assert sorted(p.name for p in thesis.iterdir()) == [io.OUTPUT_MARKER, "d.txt"]


def test_keep_partial_swaps_in_what_was_written_when_the_run_stops(tmp_path):
    out = tmp_path / "out"
    with io.atomic_dir(out, "predict") as tmp:
        (tmp / "old.txt").write_text("an earlier run")
    with pytest.raises(KeyboardInterrupt), io.atomic_dir(out, "predict", keep_partial=True) as tmp:
        (tmp / "done.txt").write_text("complete")
        raise KeyboardInterrupt
    assert sorted(p.name for p in out.iterdir()) == [io.OUTPUT_MARKER, "done.txt"]  # never mixed
    with pytest.raises(RuntimeError), io.atomic_dir(out, "predict", keep_partial=True):
        raise RuntimeError("nothing written")
    assert sorted(p.name for p in out.iterdir()) == [io.OUTPUT_MARKER, "done.txt"]  # unchanged
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_an_error_inside_atomic_dir_names_the_output_not_the_temporary(tmp_path):
    with pytest.raises(OSError) as info, io.atomic_dir(tmp_path / "out", "predict") as tmp:
        raise OSError(28, "no space left on device", str(tmp / "f_depth.npy"))
    assert info.value.filename == str(tmp_path / "out" / "f_depth.npy")


def test_folder_lock_refuses_a_second_run_and_leaves_no_file(tmp_path):
    out = tmp_path / "out"
    with io.folder_lock(out):
        assert (tmp_path / ".out.lock").read_text() == f"{os.getpid()}\n"
        with pytest.raises(BlockingIOError) as info, io.folder_lock(out):
            raise AssertionError("never entered")
        assert info.value.filename == str(out) and info.value.strerror == (
            f"another f2depth run (pid {os.getpid()}) is writing this folder now; wait for it to end or give "
            "--output another folder (nothing was changed)")
    assert list(tmp_path.iterdir()) == []
    with io.folder_lock(out):  # free again
        pass


# ---- issue 53 item 2: checkpoints carry a digest of their weights ---------------------------------------


def test_weights_digest_sees_every_byte_and_damaged_weights_says_so(tmp_path):
    import torch

    state = {"b": torch.arange(6, dtype=torch.float32).reshape(2, 3), "a": torch.tensor(3),
             "h": torch.ones(2, dtype=torch.bfloat16)}
    digest = io.weights_digest(state)
    assert digest == io.weights_digest(dict(reversed(state.items())))  # key order of the dict is irrelevant
    flipped = {**state, "b": state["b"].clone()}
    flipped["b"].view(torch.uint8)[0] ^= 1  # one bit of one weight
    assert io.weights_digest(flipped) != digest
    assert io.weights_digest({**state, "b": state["b"].reshape(3, 2)}) != digest  # the shape counts
    ckpt = {"weights_sha256": digest, "state_dict": flipped}
    assert io.damaged_weights("m.pt", ckpt, "re-run it") == (
        "m.pt: damaged: its weights do not match the sha256 digest written with them (the file changed "
        "after it was written); re-run it")
    assert io.damaged_weights("m.pt", {**ckpt, "state_dict": state}, "x") is None
    assert io.damaged_weights("m.pt", {"state_dict": flipped}, "x") is None  # written before the digest
    assert io.damaged_weights("m.pt", {**ckpt, "state_dict": [1]}, "x") is not None


def test_atomic_dir_through_a_link_replaces_the_folder_and_keeps_the_link(tmp_path):
    real = tmp_path / "real"
    with io.atomic_dir(real, "predict") as tmp:
        (tmp / "a.txt").write_text("1")
    (tmp_path / "link").symlink_to(real, target_is_directory=True)
    with io.atomic_dir(tmp_path / "link", "predict") as tmp:
        (tmp / "b.txt").write_text("2")
    assert (tmp_path / "link").is_symlink() and sorted(p.name for p in real.iterdir()) == [io.OUTPUT_MARKER,
                                                                                           "b.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]
