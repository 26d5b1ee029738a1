"""DVC stage `ingest`: the videos and image folders of `data.video` → `data.ingested` (docs/ingest.md).

Usage: python stages/ingest.py [params.yaml]
Every video and image folder in `data.video` is one scene; the camera comes from `data.video_camera` (a
camera file; null: the EXIF focal length of image folders). The frames where the camera did not move are
dropped, the rest undistorted and shrunk (`ingest` section, as `f2depth ingest`). With `train_source:
video` prepare, keypoints and poses read the result; with the default `train_source: nyu_raw` this stage
still ingests the embedded clips (synth's NYU-raw scenes as MP4), a check of the route that costs seconds.
Writes `data.ingested` (built aside, swapped in when complete) and metrics/ingest.json.
"""

import sys
from pathlib import Path

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.data.training_video import training_video
from f2depth.ingest.run import IngestConfig, ingest
from f2depth.ingest.sources import IMAGE_EXTENSIONS, VIDEO_EXTENSIONS
from f2depth.io import atomic_dir, write_json, write_text
from f2depth.stage import run_stage

METRICS = Path("metrics/ingest.json")


def holds_media(folder: str) -> bool:
    """Whether ``folder`` holds a video or an image (directly, or in one level of scene folders)."""
    exts = set(VIDEO_EXTENSIONS) | set(IMAGE_EXTENSIONS)
    root = Path(folder)
    return root.is_dir() and any(f.suffix.lower() in exts for f in (*root.iterdir(), *root.glob("*/*")))


def main(argv: list[str]) -> None:
    p = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    threads.use(P.threads(p))
    config = P.section(p, "ingest", IngestConfig)
    video, out = P.value(p, "data.video", str), P.value(p, "data.ingested", str)
    camera = P.value(p, "data.video_camera", str | None)
    if training_video(p).root != out and not holds_media(video):
        # the NYU-raw route without clips (data_source: real): nothing to check, nothing anyone reads
        with atomic_dir(out, "ingest", owned=True) as tmp:
            write_text(tmp / "README.txt", f"{video} holds no videos or images: nothing ingested\n")
        write_json(METRICS, {"scenes": 0, "sampled": 0, "kept": 0, "static": 0, "blur": 0})
        print(f"ingest: {video} holds no videos or images and train_source is not video: nothing to ingest")
        return
    summary = ingest([video], out, config, camera_file=camera, progress=True, option="data.ingested",
                     owned=True)  # DVC's output: DVC removes it itself before the stage runs
    scenes = summary["scenes"]
    metrics = {"scenes": len(scenes), "sampled": sum(s["sampled"] for s in scenes.values()),
               "kept": sum(s["kept"] for s in scenes.values()),
               "static": sum(s["static"] for s in scenes.values()),
               "blur": sum(s["blur"] for s in scenes.values()),
               "camera": summary["camera"], "input_camera": summary["input_camera"],
               "per_scene": scenes, "seconds": summary["seconds"]}
    if summary["self_calibration"] is not None:  # data.video_camera null and no EXIF: fx from the clips
        metrics["self_calibration"] = summary["self_calibration"]
    write_json(METRICS, metrics)
    tracking.mirror_stage("ingest", p, {k: metrics[k] for k in ("scenes", "sampled", "kept", "static", "blur",
                                                               "seconds")})
    for text in summary["warnings"]:  # e.g. a damaged video ingested from the frames that decode
        print(f"ingest: warning: {text}", file=sys.stderr)
    cam = summary["camera"]
    print(f"ingest: {metrics['scenes']} scene(s) of {video}, kept {metrics['kept']} of {metrics['sampled']} "
          f"frames ({metrics['static']} static, {metrics['blur']} blurred dropped), {cam['width']}×"
          f"{cam['height']}, fx {cam['K'][0][0]:.1f} px ({summary['input_camera']['intrinsics_source']}) in "
          f"{summary['seconds']} s → {out}")


if __name__ == "__main__":
    run_stage("ingest", main, sys.argv)
