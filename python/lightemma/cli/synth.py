"""``lightemma synth OUTDIR``: write a synthetic nuScenes-format dataset for offline use."""

from __future__ import annotations

import argparse
import sys

DEFAULT_VERSION = "v1.0-mini"


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"image size must look like 800x450, got {text!r}") from None
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"image size {text} is too small")
    return w, h


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "synth",
        help="write a small synthetic nuScenes-format dataset (offline demos and tests)",
        description=(
            "Write a synthetic nuScenes-format dataset that the unmodified nuscenes-devkit loads: "
            "the 13 tables, a base map mask and a map expansion (drivable area, lanes, lane connectors, road "
            "segments, car parks), CAN-bus-like pose messages (can_bus/<scene>_pose.json), CAM_FRONT keyframes "
            "(2 Hz) and sweeps (12 Hz) as JPEGs. "
            "Scenes cycle through: cruise, accelerate, brake-red-light, wait-then-go-green, "
            "stopped-behind-lead-green, left-turn, right-turn, straight-after-turn. "
            "As v1.0-mini (the default) it loads with all its scenes; under another --version name, "
            "use --split all (or --scenes): the devkit's splits name real nuScenes scenes."
        ),
    )
    parser.add_argument("outdir", help="folder to write (dataroot)")
    parser.add_argument("--scenes", type=_positive, default=8, help="number of scenes (default 8)")
    parser.add_argument("--seed", type=int, default=0, help="random seed; same seed, same dataset (default 0)")
    parser.add_argument("--version", default=DEFAULT_VERSION, help=f"version folder name (default {DEFAULT_VERSION})")
    parser.add_argument("--keyframes", type=_positive, default=40, help="keyframes per scene (default 40)")
    parser.add_argument(
        "--image-size",
        type=_size,
        default=(800, 450),
        metavar="WxH",
        help="image size (default 800x450; nuScenes is 1600x900)",
    )
    parser.add_argument("--no-images", action="store_true", help="write the tables only (no JPEGs)")
    parser.add_argument("--no-sweeps", action="store_true", help="keyframes only, no 12 Hz sweeps")
    parser.add_argument("--force", action="store_true", help="replace an existing version folder")
    parser.set_defaults(func=run)
    return parser


def run(args: argparse.Namespace) -> int:
    from lightemma.nuscenes import window_range
    from lightemma.synth import write_dataset

    root = write_dataset(
        args.outdir,
        scenes=args.scenes,
        seed=args.seed,
        version=args.version,
        keyframes=args.keyframes,
        images=not args.no_images,
        sweeps=not args.no_sweeps,
        image_size=args.image_size,
        overwrite=args.force,
        progress=sys.stderr.isatty(),
    )
    frames = len(window_range(args.keyframes, "reference")) * args.scenes
    print(
        f"wrote {args.scenes} synthetic scenes ({args.keyframes} keyframes each, {frames} frames in the "
        f"reference window) to {root}/{args.version}"
    )
    if not frames:
        full = len(window_range(args.keyframes, "full")) * args.scenes
        print(
            f"lightemma synth: warning: a scene needs at least 15 keyframes for a frame in the reference window "
            f"(14 for --window full); with --keyframes {args.keyframes} "
            + ("there is no frame to run" if not full else f"only --window full has frames ({full})"),
            file=sys.stderr,
        )
    # v1.0-mini takes all of its scenes by default; any other version folder must say so
    split = ("", "") if args.version == DEFAULT_VERSION else (" --split all", ", split='all'")
    if args.no_images:  # runs skip frames without their CAM_FRONT image: only the tables are of use
        print(
            f"tables only (--no-images): runs need the images; load the frames in Python with "
            f"lightemma.load_frames({str(root)!r}, {args.version!r}{split[1]}, on_missing_image='keep')"
        )
        return 0
    print(
        f"run a baseline on it: lightemma run --model baseline:cv --dataroot {root} --version {args.version}{split[0]}"
    )
    print(f"load it in Python:    lightemma.load_frames({str(root)!r}, {args.version!r}{split[1]})")
    return 0
