"""The ``f2depth`` command: ``predict``, ``export`` and ``reconstruct`` (f2depth.inference does the work).

Exit codes: 0 success; 1 bad input (the one line on stderr names the file and the problem); 2 wrong
command-line usage; 3 an optional dependency is missing; 130 interrupted, 143 terminated by SIGTERM (files
already written are complete: every output is written atomically). Every error is one line on stderr;
warnings (e.g. a video that decodes to fewer frames than its container announces) are lines starting
``f2depth <command>: warning:``. Numbers must be finite, devices available, export sizes and opsets
within the bounds of ``f2depth.inference.limits``.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

from f2depth.inference.limits import (
    DEFAULT_OPSET,
    MAX_OPSET,
    MAX_SIDE,
    MIN_OPSET,
    MIN_SIDE,
    check_export_size,
)
from f2depth.params import DEVICES, device_problem

EXIT_INPUT, EXIT_USAGE, EXIT_MISSING, EXIT_INTERRUPTED, EXIT_TERMINATED = 1, 2, 3, 130, 143

RELATIVE_NOTE = """\
Depth is RELATIVE: the networks are self-supervised (trained from video without depth), so a prediction
is correct up to one unknown scale factor per scene. Its values lie in the network's nominal range
(0.1-10 "metres") but are not metric. To make them metric give either --scale S (every depth is
multiplied by S, e.g. a factor measured once for your camera) or --scale-from FILE, a reference depth
map of the first frame (16-bit PNG in millimetres, 0/65535 = no depth, or a .npy in metres): the factor
median(reference) / median(prediction) over the reference's valid pixels is applied to every frame."""

PREDICT_DESCRIPTION = """\
Predict depth for an image, a folder of images (sorted by name; other file types ignored) or a video
(OpenCV/FFmpeg). Each frame is resized to the network's training size, predicted, and its disparity
resized back to the frame's size."""

PREDICT_EPILOG = """\
Writes per frame (video frames are named frame_000000, ...):
  <name>_depth_mm.png     uint16 depth in millimetres (0 = no depth; clipped to 1..65534)
  <name>_depth.npy        float32 depth in metres
  <name>_depth_color.png  colour-mapped disparity (magma)
  <name>_points.ply       with --ply: coloured points in the camera frame (x right, y down, z forward)
and predict.json (scale, model, intrinsics). Every file is written atomically; the folder is built aside
and swapped in, and replaces only an empty folder or an earlier predict's.
exit codes: 0 ok, 1 bad input, 2 usage error, 3 optional dependency missing, 130 interrupted, 143
terminated (SIGTERM)"""

RECONSTRUCT_DESCRIPTION = """\
Fuse a sequence's predicted depth with its known poses into a TSDF volume (Open3D's
ScalableTSDFVolume, optional extra 'recon') and write a coloured triangle mesh (.ply, marching cubes).
Poses come from 7-Scenes .pose.txt files or from the synthetic ground truth (.npz). Predicted depth
is relative, so it is scaled to the reference depth (the 7-Scenes Kinect depth or the ground truth)
by median ratios (--scaling), or by a fixed --scale."""

EXPORT_DESCRIPTION = """\
Export the depth network (image (B,3,H,W) in [0,1] -> depth (B,1,H,W), dynamic batch) and check the
export against PyTorch with onnxruntime (max abs difference printed); nothing is written if it fails."""

EXIT_NOTE = ("exit codes: 0 ok, 1 bad input, 2 usage error, 3 optional dependency missing, 130 interrupted, "
             "143 terminated (SIGTERM)")


class UsageError(Exception):
    """Inconsistent options that argparse cannot express."""


class OneLineParser(argparse.ArgumentParser):
    """argparse with a one-line usage error (the full usage is one ``--help`` away)."""

    def error(self, message: str):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def _positive_int(text: str) -> int:
    value = _integer(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be ≥ 1, got {value}")
    return value


def _positive_float(text: str) -> float:
    value = _finite(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def _export_side(text: str) -> int:
    value = _integer(text)
    if value % 32 or not MIN_SIDE <= value <= MAX_SIDE:
        raise argparse.ArgumentTypeError(f"must be a multiple of 32 in {MIN_SIDE}..{MAX_SIDE}, got {value}")
    return value


def _opset(text: str) -> int:
    value = _integer(text)
    if not MIN_OPSET <= value <= MAX_OPSET:
        raise argparse.ArgumentTypeError(f"ONNX opset must be in {MIN_OPSET}..{MAX_OPSET} (the opsets "
                                         f"torch's exporter writes for this network), got {value}")
    return value


def _device(text: str) -> str:
    """One of :data:`f2depth.params.DEVICES` that this machine has (params.yaml's grammar)."""
    problem = device_problem(text)
    if problem is not None:
        raise argparse.ArgumentTypeError(problem)
    return text


def _add_network(p: argparse.ArgumentParser, required: bool = True) -> None:
    group = p.add_mutually_exclusive_group(required=required)
    group.add_argument("--model", type=Path, metavar="M",
                       help="depth checkpoint (f2depth.depth .pt, e.g. models/depth_<variant>/model.pt)")
    group.add_argument("--onnx", type=Path, metavar="F",
                       help="run an ONNX export (f2depth export) with onnxruntime instead of PyTorch")
    p.add_argument("--post-process", action="store_true",
                   help="Monodepth's flip post-processing (predicts image and mirror image, blends; 2× time)")
    p.add_argument("--batch-size", type=_positive_int, default=4, help="frames per network call (default 4)")
    p.add_argument("--device", type=_device, default="auto",
                   help=f"{DEVICES} (default auto: cuda when available)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (default: bar on a terminal)")


def _add_threads(p: argparse.ArgumentParser) -> None:
    p.add_argument("--threads", type=_positive_int, metavar="N",
                   help="CPU threads of torch, OpenCV and onnxruntime (default: $OMP_NUM_THREADS, else the "
                        "CPUs this process may use); on a shared machine give the free cores")


#: help texts keep their line breaks (every command's description and epilog are laid out by hand)
PLAIN = argparse.RawDescriptionHelpFormatter


def build_parser() -> argparse.ArgumentParser:
    about = "F2Depth: self-supervised indoor monocular depth. Use a trained model."
    parser = OneLineParser(prog="f2depth", description=about, epilog=EXIT_NOTE)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_predict(sub)
    _add_ingest(sub)
    _add_export(sub)
    _add_reconstruct(sub)
    return parser


def _add_predict(sub: argparse._SubParsersAction) -> None:
    """The `predict` command: depth maps of an image, a folder or a video."""
    p = sub.add_parser("predict", formatter_class=PLAIN, help="depth maps of an image, a folder or a video",
                       description=PREDICT_DESCRIPTION + "\n\n" + RELATIVE_NOTE, epilog=PREDICT_EPILOG)
    _add_threads(p)
    _add_network(p)
    p.add_argument("--input", type=Path, required=True, metavar="PATH",
                   help="image, folder of images or video")
    p.add_argument("--output", type=Path, required=True, metavar="DIR",
                   help="output folder: new, empty or an earlier predict's (replaced as a whole)")
    scale = p.add_mutually_exclusive_group()
    scale.add_argument("--scale", type=_positive_float, metavar="S", help="multiply every depth by S")
    scale.add_argument("--scale-from", type=Path, metavar="FILE",
                       help="reference depth of the first frame (mm PNG or metres .npy): median scaling")
    p.add_argument("--ply", action="store_true", help="also write a coloured point cloud per frame")
    p.add_argument("--fx", type=_positive_float,
                   help="focal length x in pixels of the input image, for --ply "
                        "(default: NYU Depth V2's field of view, fx = fy = 0.811*W)")
    p.add_argument("--fy", type=_positive_float, help="focal length y in pixels (default fx)")
    p.add_argument("--cx", type=_finite, help="principal point x in pixels (default (W-1)/2)")
    p.add_argument("--cy", type=_finite, help="principal point y in pixels (default (H-1)/2)")
    p.add_argument("--upsample", choices=("bilinear", "nearest"), default="bilinear",
                   help="resizing of the disparity back to the input size (default bilinear)")
    p.set_defaults(func=_cmd_predict)


def _add_ingest(sub: argparse._SubParsersAction) -> None:
    """The `ingest` command: videos and image folders → a raw frame folder."""
    p = sub.add_parser("ingest", formatter_class=PLAIN,
                       help="your videos / image folders → a raw frame folder to train on (docs/ingest.md)",
                       description="Each video or image folder becomes one scene of OUT (NYU-raw layout, "
                                   "camera.json, scenes.txt, ingest.json). Defaults: params.yaml's ingest "
                                   "section; the flags override it.")
    _add_threads(p)
    p.add_argument("inputs", type=Path, nargs="+", metavar="INPUT", help="videos and/or folders of images")
    p.add_argument("--out", type=Path, required=True, metavar="DIR",
                   help="output folder: new, empty or an earlier ingest's (replaced as a whole)")
    cam = p.add_mutually_exclusive_group()
    cam.add_argument("--camera", type=Path, metavar="FILE",
                     help="intrinsics: our JSON/YAML, COLMAP cameras.txt or an OpenCV calibration YAML")
    cam.add_argument("--fov", type=_positive_float, metavar="DEG",
                     help="horizontal field of view, degrees (neither, and no EXIF: the focal length is "
                          "self-calibrated from the video)")
    p.add_argument("--params", type=Path, default=Path("params.yaml"), metavar="FILE",
                   help="parameter file with the ingest section (default params.yaml)")
    p.add_argument("--frame-step", type=_positive_int, metavar="N", help="every N-th frame is a candidate")
    p.add_argument("--rate", type=_positive_float, metavar="HZ", help="videos: about HZ candidates a second")
    p.add_argument("--min-motion", type=_finite, metavar="S",
                   help="keep a frame when the median tracked motion is ≥ S × the diagonal")
    p.add_argument("--min-sharpness", type=_finite, metavar="V", help="drop frames whose Laplacian variance "
                   "is below V (0: off)")
    p.add_argument("--max-side", type=_positive_int, metavar="PX", help="long side of the written frames")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_ingest)


def _add_export(sub: argparse._SubParsersAction) -> None:
    """The `export` command: the depth network as ONNX."""
    p = sub.add_parser("export", formatter_class=PLAIN, help="export the depth network (ONNX)",
                       description=EXPORT_DESCRIPTION, epilog=EXIT_NOTE)
    _add_threads(p)
    p.add_argument("--model", type=Path, required=True, metavar="M", help="depth checkpoint (.pt)")
    p.add_argument("--format", choices=("onnx",), default="onnx", help="export format (onnx)")
    p.add_argument("--output", type=Path, required=True, metavar="F", help="output file (.onnx)")
    p.add_argument("--height", type=_export_side,
                   help=f"input height, a multiple of 32 in {MIN_SIDE}..{MAX_SIDE} (default: the training "
                        "height); height × width at most 2048×2048")
    p.add_argument("--width", type=_export_side,
                   help="input width, as --height (default: the training width)")
    p.add_argument("--opset", type=_opset, default=DEFAULT_OPSET,
                   help=f"ONNX opset, {MIN_OPSET}..{MAX_OPSET} (default {DEFAULT_OPSET})")
    p.set_defaults(func=_cmd_export)


def _add_reconstruct(sub: argparse._SubParsersAction) -> None:
    """The `reconstruct` command: TSDF fusion of a posed sequence."""
    p = sub.add_parser("reconstruct", formatter_class=PLAIN, help="TSDF fusion of a posed sequence → mesh",
                       description=RECONSTRUCT_DESCRIPTION, epilog=EXIT_NOTE)
    _add_threads(p)
    _add_network(p, required=False)
    p.add_argument("--sequence", type=Path, required=True, metavar="DIR",
                   help="7-Scenes <scene>/seq-XX folder, or a folder of the sequence's images")
    p.add_argument("--poses", choices=("7scenes", "synth"), default="7scenes",
                   help="7scenes: frame-*.pose.txt and 7-Scenes K; synth: <key>.npz in --gt "
                        "(default 7scenes)")
    p.add_argument("--gt", type=Path, metavar="DIR", help="synthetic ground-truth folder for --poses synth")
    p.add_argument("--output", type=Path, required=True, metavar="MESH", help="output mesh (.ply)")
    p.add_argument("--stride", type=_positive_int, default=1, help="use every N-th frame (default 1)")
    p.add_argument("--max-frames", type=_positive_int, help="use at most this many frames")
    p.add_argument("--scaling", choices=("sequence", "frame", "fixed"), default="sequence",
                   help="sequence: one factor, the median of per-frame median ratios (default); frame: "
                        "per-frame median ratio; fixed: --scale")
    p.add_argument("--scale", type=_positive_float, default=1.0,
                   help="factor for --scaling fixed (default 1)")
    p.add_argument("--depth-source", choices=("predicted", "reference"), default="predicted",
                   help="fuse the predicted depth (default) or the reference depth (a sanity check)")
    p.add_argument("--voxel", type=_positive_float, default=0.02,
                   help="voxel size in metres (default 0.02)")
    p.add_argument("--trunc", type=_positive_float, help="TSDF truncation in metres (default 4 voxels)")
    p.add_argument("--max-depth", type=_positive_float, default=5.0,
                   help="ignore depth beyond this (m, default 5)")
    p.add_argument("--evaluate", action="store_true",
                   help="compare with the mesh fused from the reference depth: accuracy, completeness")
    p.add_argument("--threshold", type=_positive_float, default=0.05,
                   help="distance (m) for completeness/precision (default 0.05)")
    p.add_argument("--reference-mesh", type=Path, metavar="MESH", help="also write the reference mesh")
    p.add_argument("--metrics", type=Path, metavar="FILE", help="write the summary and metrics as JSON")
    p.set_defaults(func=_cmd_reconstruct)

def _out(text: str) -> None:
    sys.stdout.write(text + "\n")


def _cmd_predict(args: argparse.Namespace) -> int:
    from f2depth.formats.writable import check_apart
    from f2depth.inference.backends import load_backend
    from f2depth.inference.predict import Predictor, PredictSettings, run_predict
    from f2depth.ingest.sources import check_output_apart, open_source
    from f2depth.threads import budget

    check_output_apart(args.input, args.output)
    # predict swaps its output folder in as a whole: it may lie inside the input folder, not hold an input
    check_apart((args.input, args.model, args.onnx, args.scale_from), args.output, inside_ok=True)
    source = open_source(args.input)
    backend = load_backend(args.model, args.onnx, args.device, budget(args.threads))
    settings = PredictSettings(args.output, batch_size=args.batch_size, scale=args.scale,
                               scale_from=args.scale_from, ply=args.ply,
                               K_args={"fx": args.fx, "fy": args.fy, "cx": args.cx, "cy": args.cy},
                               progress=False if args.no_progress else None)
    predictor = Predictor(backend, post_process=args.post_process, upsample=args.upsample)
    summary = run_predict(source, predictor, settings, total=len(source), input_desc=str(args.input),
                          renamed=source.renamed)
    kind = "metric" if summary["metric"] else "relative (no --scale/--scale-from)"
    _out(f"wrote {summary['frames']} frame(s) to {args.output} ({backend.name}, "
         f"scale {summary['scale']:.4g}, {kind})")
    for text in summary["warnings"]:
        _warn(args.command, text)
    return 0


def _warn(command: str, text: str) -> None:
    sys.stderr.write(f"f2depth {command}: warning: {' '.join(str(text).split())}\n")


def _cmd_ingest(args: argparse.Namespace) -> int:
    from f2depth import params as P
    from f2depth.ingest.run import IngestConfig, ingest

    params = P.load(args.params)
    flags = {"frame_step": args.frame_step, "rate": args.rate, "min_motion": args.min_motion,
             "min_sharpness": args.min_sharpness, "max_side": args.max_side}
    given = {k: v for k, v in flags.items() if v is not None}
    names = {k: "--" + k.replace("_", "-") for k in given}  # a flag's value is the flag's, in every message
    given = {k: P.check_field(IngestConfig, k, v, names[k]) for k, v in given.items()}
    params["ingest"] = {**P.get(params, "ingest"), **given}
    config = P.section(params, "ingest", IngestConfig)
    summary = ingest(args.inputs, args.out, config, camera_file=args.camera, fov=args.fov,
                     progress=not args.no_progress, names=names)
    for scene, r in summary["scenes"].items():
        _out(f"{scene}: kept {r['kept']} of {r['sampled']} sampled frames ({r['static']} static, "
             f"{r['blur']} blurred dropped; {r['untracked']} kept untracked)")
    for text in summary["warnings"]:
        _warn(args.command, text)
    cam = summary["camera"]
    _out(f"wrote {len(summary['scenes'])} scene(s) to {args.out}: {cam['width']}×{cam['height']}, fx "
         f"{cam['K'][0][0]:.1f} px ({summary['input_camera']['intrinsics_source']})")
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from f2depth.formats.writable import check_output_file
    from f2depth.inference.backends import load_depth_model
    from f2depth.inference.export import export_onnx

    _check_suffix(args.output, ".onnx", "--output", "the ONNX model")
    check_output_file(args.output)
    model = load_depth_model(args.model, "cpu")
    trained = (model.config.height, model.config.width)
    try:
        check_export_size(args.height or trained[0], args.width or trained[1])
    except ValueError as exc:
        raise UsageError(f"{exc} (--height/--width; {args.model} was trained at "
                         f"{trained[0]}×{trained[1]})") from None
    if (args.height or trained[0], args.width or trained[1]) != trained:
        _warn(args.command, f"exporting at {args.height or trained[0]}×{args.width or trained[1]}, but "
                            f"{args.model} was trained at {trained[0]}×{trained[1]}: the export's depth will "
                            "not be the model's (`predict --model` and `--onnx` disagree); leave out "
                            "--height/--width for the training size")
    parity = export_onnx(model, args.output, args.height, args.width, opset=args.opset,
                         source=str(args.model))
    h, w = parity.hw
    _out(f"wrote {args.output} ({h}×{w}, dynamic batch, opset {args.opset})")
    _out(f"parity vs PyTorch on {parity.batch} images: max abs difference {parity.max_abs:.3g} m "
         f"(max relative {parity.max_rel:.3g})")
    return 0


def _cmd_reconstruct(args: argparse.Namespace) -> int:
    from f2depth.formats.writable import check_output_file
    from f2depth.inference.backends import load_backend, size_mismatch
    from f2depth.inference.predict import Predictor
    from f2depth.inference.reconstruct import ReconstructSettings, TSDFSettings, reconstruct
    from f2depth.inference.sequences import sevenscenes_sequence, synth_sequence
    from f2depth.io import write_json
    from f2depth.threads import budget

    if args.depth_source == "predicted" and args.model is None and args.onnx is None:
        raise UsageError("give --model or --onnx (or --depth-source reference)")
    if args.poses == "synth" and args.gt is None:
        raise UsageError("--poses synth needs --gt DIR (the sequence's ground-truth .npz folder)")
    for option, path in (("--output", args.output), ("--reference-mesh", args.reference_mesh),
                         ("--metrics", args.metrics)):
        if path is not None:
            if option != "--metrics":
                _check_suffix(path, ".ply", option, "the mesh (a binary PLY)")
            check_output_file(path, option)
    tsdf = TSDFSettings(voxel=args.voxel, trunc=args.trunc, max_depth=args.max_depth)
    if args.poses == "synth":
        frames = synth_sequence(args.sequence, args.gt, args.stride, args.max_frames)
    else:
        frames = sevenscenes_sequence(args.sequence, args.stride, args.max_frames)
    predictor = None
    if args.depth_source == "predicted":
        backend = load_backend(args.model, args.onnx, args.device, budget(args.threads))
        predictor = Predictor(backend, post_process=args.post_process)
        mismatch = size_mismatch(backend)
        if mismatch is not None:
            _warn(args.command, mismatch)
    settings = ReconstructSettings(args.output, tsdf=tsdf, scaling=args.scaling, scale=args.scale,
                                   depth_source=args.depth_source, evaluate=args.evaluate,
                                   reference_mesh=args.reference_mesh, threshold=args.threshold,
                                   batch_size=args.batch_size, progress=False if args.no_progress else None)
    summary = reconstruct(frames, predictor, settings)
    summary["sequence"] = str(args.sequence)
    if args.metrics is not None:
        write_json(args.metrics, summary)
    _out(f"wrote {args.output}: {summary['vertices']} vertices, {summary['triangles']} triangles from "
         f"{summary['frames']} frames (depth scale {summary['scale_median']:.4g}, {summary['scaling']})")
    if "metrics" in summary:
        m = summary["metrics"]
        _out(f"vs reference: accuracy mean {m['accuracy_mean']:.4f} m, median {m['accuracy_median']:.4f} m; "
             f"completeness {m['completeness']:.3f}, precision {m['precision']:.3f}, F {m['fscore']:.3f} "
             f"(< {m['threshold']:g} m)")
    return 0


def _check_suffix(path: Path, suffix: str, option: str, what: str) -> None:
    """A file name whose extension says another format than the one written → UsageError (a PLY named
    .png would be opened as an image)."""
    if path.suffix.lower() != suffix:
        raise UsageError(f"{option} {path}: {what} is written as {suffix}, so the name must end in {suffix}")


def _fail(command: str, message: str, code: int) -> int:
    from f2depth.params import MAX_LINE, clip

    text = clip(" ".join(str(message).split()), MAX_LINE)  # exactly one line, of a readable length
    sys.stderr.write(f"f2depth {command}: error: {text}\n")
    return code


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (argparse exits with 2 itself on usage errors, in one
    line)."""
    args = build_parser().parse_args(argv)
    from f2depth import threads
    from f2depth.errors import DataError
    from f2depth.inference.export import ExportError
    from f2depth.inference.optional import MissingDependency
    from f2depth.params import ParamsError
    from f2depth.signals import Terminated, sigterm_as_interrupt

    try:
        threads.use(args.threads, follow_free_cores=True)  # inference: the count changes no result
        with sigterm_as_interrupt():  # SIGTERM ends the run as Ctrl-C does
            return args.func(args)
    except UsageError as exc:
        return _fail(args.command, str(exc), EXIT_USAGE)
    except MissingDependency as exc:
        return _fail(args.command, str(exc), EXIT_MISSING)
    except (DataError, ParamsError, ExportError) as exc:
        return _fail(args.command, str(exc), EXIT_INPUT)
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        return _fail(args.command, f"{where}{exc.strerror or exc}", EXIT_INPUT)
    except Terminated:
        return _fail(args.command, "terminated (SIGTERM); every file written so far is complete",
                     EXIT_TERMINATED)
    except KeyboardInterrupt:
        return _fail(args.command, "interrupted; every file written so far is complete", EXIT_INTERRUPTED)
    except MemoryError:
        return _fail(args.command, "out of memory; every file written so far is complete: use smaller "
                                   "inputs or a smaller --batch-size", EXIT_INPUT)
    except (RuntimeError, ValueError) as exc:  # last resort (torch, OpenCV, Open3D): one line, not a trace
        first = str(exc).strip().splitlines()[0][:300] if str(exc).strip() else ""
        return _fail(args.command, f"{type(exc).__name__}: {first}; every file written so far is complete",
                     EXIT_INPUT)


if __name__ == "__main__":
    sys.exit(main())
