"""DVC stage `synth`: generate the embedded synthetic datasets below ``synth.root``.

Params: synth, data_source.

Usage: python stages/synth.py [params.yaml]
The generated sets use the standard layout below ``synth.root`` (data/raw), which the default ``data.*``
paths point at. With ``data_source: real`` nothing is generated (the root only gets a README saying so):
point the ``data.*`` paths at your copies, which this stage never writes or deletes.
"""

import sys
from pathlib import Path
from typing import Literal

from f2depth import params as P
from f2depth import threads, tracking
from f2depth.io import write_json, write_text
from f2depth.stage import run_stage
from f2depth.synth import OutputPaths, SynthConfig, generate

METRICS = Path("metrics/synth.json")


def config_from_params(params: dict) -> SynthConfig:
    return SynthConfig.from_params(P.get(params, "synth"), params["_file"])


def main(argv: list[str]) -> None:
    params = P.load(argv[1] if len(argv) > 1 else P.DEFAULT_PARAMS)
    threads.use(P.threads(params))
    data_source = P.value(params, "data_source", Literal["synthetic", "real"])
    cfg = config_from_params(params)
    root = Path(P.value(params, "synth.root", str))
    if data_source == "real":
        note = "data_source is 'real': nothing generated here; see params.yaml data.*\n"
        write_text(root / "README.txt", note)
        write_text(root / "synth_gt" / "README.txt", note)
        write_text(root / "clips" / "README.txt", note)  # data.video must exist: DVC tracks it
        write_json(METRICS, {"data_source": "real", "generated": False, "frames": 0})
        print("synth: data_source is 'real', nothing generated")
        return
    paths = OutputPaths.under(root)
    metrics = generate(cfg, paths)
    metrics["generated"] = True
    write_json(METRICS, metrics)
    tracking.mirror_stage("synth", params, metrics)
    print(f"synth: {metrics['frames']} frames in {metrics['seconds']:.1f} s")


if __name__ == "__main__":
    run_stage("synth", main, sys.argv)
