"""``bubblefit fit-sequence FRAMES... --envmap ENV [...as fit] -o OUT_DIR``.

Fits every frame of a sequence (image files, a folder, or a video read through OpenCV),
warm-starting each frame from its neighbour, on a local Dask cluster (default), an
existing one (``--scheduler``) or in this process (``--workers 0``). Writes
``OUT_DIR/params.csv`` and ``OUT_DIR/params.jsonl`` (one row per frame), ``thickness.png``
(thickness against time) and ``frames/`` (one JSON per finished frame: a rerun resumes).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from ..errors import InputError
from .fit import add_model_options, build_fit_options, check_photo_size, load_envmap
from .view_options import add_view_options, check_view_args, sequence_view


def register(sub):
    from .common import input_file, output_file, output_folder
    from ..model.modes import MODEL_CHOICES, THICKNESS_KINDS  # no JAX: --help stays fast

    p = sub.add_parser(
        "fit-sequence",
        help="fit every frame of a sequence or video (warm starts, Dask, resumable)",
        description="Fit the bubble model to every frame of a sequence: image files, a folder of images or a "
                    "video file. Each frame starts from its neighbour's result; finished frames are saved at "
                    "once, so an interrupted run resumes where it stopped.",
    )
    p.add_argument("frames", nargs="+", metavar="FRAMES", type=input_file, help="image files, a folder of images, or a video file")
    p.add_argument("--envmap", required=True, type=input_file, help="environment map (equirectangular, linear EXR/HDR)")
    p.add_argument("--background", metavar="BEFORE", type=input_file, help="photo of the same view without the bubble (linear use)")
    cal = p.add_mutually_exclusive_group()
    cal.add_argument("--calibration", metavar="CAL.json", type=input_file, help="output of `bubblefit calibrate` (t and the disc)")
    cal.add_argument("--t", type=float, help="starting transmission fraction t (0 < t < 1)")
    p.add_argument("--scene", metavar="SCENE.toml", type=input_file, help="scene file: its camera and the values it sets are held")
    p.add_argument("--thickness", choices=THICKNESS_KINDS, default="constant",
                   help="thickness model of each frame (default: constant)")
    p.add_argument("--model", choices=MODEL_CHOICES, default=None,
                   help="forward model, as in `fit` (default: the scene's, else auto: the model that explains the "
                        "paper model's search image better first, the other one when it does not explain a frame)")
    p.add_argument("--disc", metavar="CX,CY,R",
                   help="the bubble's disc in pixels (default: from --calibration, else detected on the first frame)")
    p.add_argument("--thickness-range", metavar="MIN,MAX", default="50,2000",
                   help="thickness range searched, nm (default: 50,2000)")
    p.add_argument("--hold", metavar="NAMES", default="",
                   help="comma-separated parameters held at their starting values (e.g. t,roughness)")
    p.add_argument("--set", metavar="NAME=VALUE", action="append", default=[],
                   help="a parameter's starting value (t, f, r_d, r_s, roughness, thickness_nm, exposure, "
                        "rotation_deg, top_nm, bottom_nm, exponent); repeat for several, --hold NAME to hold it")
    p.add_argument("--max-steps", type=int, default=None, help="solver step limit per frame")
    p.add_argument("-o", "--output", required=True, metavar="OUT_DIR", type=output_folder, help="output folder (created; reused to resume)")
    p.add_argument("--json", metavar="PATH", type=output_file, help="write a summary of the run as JSON")
    p.add_argument("--fps", type=float, default=None,
                   help="frames per second for the time axis (default: the video's; 1 for image files)")
    p.add_argument("--maps", action="store_true", help="write each frame's thickness map to OUT_DIR/maps/")
    p.add_argument("--workers", type=int, default=None,
                   help="local Dask workers (default: one per core); 0 fits in this process without Dask; "
                        "with --scheduler, use at most this many of the cluster's workers")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tls://host:8786 (with --scheduler-security) or "
                        "tcp://host:8786 (unencrypted, for a private network only)")
    p.add_argument("--scheduler-security", metavar="FILE", type=input_file,
                   help="TOML file naming the TLS files of a tls:// scheduler: tls_ca_file, tls_client_cert "
                        "and optionally tls_client_key (see docs/safety.md)")
    p.add_argument("--chunk-size", type=int, default=8,
                   help="frames per task, fitted in order with warm starts (default: 8)")
    p.add_argument("--batch", type=int, default=1, metavar="N",
                   help="fit N warm-started frames together in one vectorised solve (default 1: frame after "
                        "frame, faster on CPUs; larger for accelerators)")
    p.add_argument("--no-warm-start", action="store_true",
                   help="run the global thickness search on every frame (frames that are not one continuous film)")
    p.add_argument("--force", action="store_true",
                   help="refit frames already finished in OUT_DIR (also when its run.json is missing or unreadable)")
    p.add_argument("--retry-failed", action="store_true", help="refit frames recorded as failed")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_model_options(p)
    add_view_options(p)
    from .photo_args import add_photo_options

    add_photo_options(p)
    p.set_defaults(func=run)


def frame_bits(frames) -> int | None:
    """Bit depth of the first frame for the noise model, as ``fit`` reads it from its photo:
    None for linear (float) files, else 8 or 16; video frames are 8-bit unless 16-bit."""
    from ..io.images import read_image

    first = frames[0]
    if first.video_frame is not None:
        return 8
    img = read_image(first.source)
    check_photo_size(img, first.source)
    return None if img.linear_file else int(img.bit_depth)


def run(args) -> int:
    from ..inverse.sequence import SequenceOptions, discover_frames, fit_sequence, row_ok
    from ..model.scene import load_scene
    from ..progress import stage, status
    from .common import guard_args, scene_inputs, write_json

    if args.chunk_size < 1:
        raise InputError("--chunk-size must be at least 1")
    if args.batch < 1:
        raise InputError("--batch must be at least 1")
    if args.workers is not None and args.workers < 0:
        raise InputError("--workers must be 0 or more")
    from dataclasses import replace

    from ..io.camera_files import read_photo
    from .photo_args import photo_reading

    reading = photo_reading(args)
    frames = discover_frames(args.frames, fps=args.fps)
    if not reading.plain:
        frames = [replace(f, reading=reading) for f in frames]
    scene = load_scene(args.scene) if args.scene else None
    out = Path(args.output)
    guard_args(args, inputs=[f.source for f in frames]
               + (scene_inputs(scene) if scene is not None else []),
               outputs=[out / "params.csv", out / "params.jsonl", out / "thickness.png", out / "run.json"]
               if out.is_dir() else [])
    check_view_args(args)
    options = build_fit_options(args, scene, frame_bits(frames), sequence_view(args, frames))
    with stage("reading the environment map"):
        env = load_envmap(args.envmap)
        background = read_photo(args.background, reading, what="background").pixels if args.background else None
    where = ("this process" if args.workers == 0 else
             f"Dask scheduler {args.scheduler}" if args.scheduler else
             f"a local Dask cluster of {args.workers or os.cpu_count()} workers")
    status(f"{len(frames)} frames, fitting on {where} ...")
    if args.scheduler_security and not args.scheduler:
        raise InputError("--scheduler-security needs --scheduler tls://HOST:PORT")
    scheduler = None
    if args.scheduler and args.workers != 0:
        from ..inverse import SchedulerAddress

        scheduler = SchedulerAddress(args.scheduler, args.scheduler_security)
    seq = SequenceOptions(scheduler=scheduler, workers=args.workers,
                          chunk_size=args.chunk_size, force=args.force, retry_failed=args.retry_failed,
                          maps=args.maps, progress=not args.no_progress, warm_start=not args.no_warm_start,
                          batch=args.batch)
    res = fit_sequence(frames, env, args.output, options, seq, background=background, scene=scene)
    rate = f"{res.fps:.2f} frames/s" if math.isfinite(res.fps) else "nothing to fit"
    flagged = sum(1 for r in res.records if r.get("status") == "ok" and not row_ok(r))
    print(f"wrote {res.table} ({len(res.records)} frames: {res.fitted} fitted, {res.skipped} already done, "
          f"{res.failed} failed, {flagged} not ok; {rate})")
    if args.json:
        write_json(args.json, {
            "out_dir": str(res.out_dir), "table": str(res.table), "jsonl": str(res.jsonl),
            "plot": None if res.plot is None else str(res.plot), "frames": len(res.records),
            "fitted": res.fitted, "skipped": res.skipped, "failed": res.failed, "workers": res.workers,
            "elapsed_s": res.elapsed_s, "setup_s": res.setup_s, "fps": res.fps,
            "camera": None if options.view is None else options.view.to_json(),
            "failures": [{"frame": r["frame"], "file": r["file"], "reason": r.get("message", "")}
                         for r in res.records if r.get("status") != "ok"],
            "flagged": [{"frame": r["frame"], "file": r["file"], "warnings": r.get("warnings", [])}
                        for r in res.records if r.get("status") == "ok" and not row_ok(r)],
        })
    return 0
