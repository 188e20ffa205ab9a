"""``gimbal-lab show``: the command line of :mod:`gimbal_lab.show`.

Registered in :mod:`gimbal_lab.cli` through :func:`add_parsers`; nothing heavy is imported until
the command runs. The clip's path is checked before any run is computed.
"""

from __future__ import annotations

from pathlib import Path

from .cli import nonnegative_int, positive_int

#: Where a clip goes when ``--out`` is not given (``gimbal_lab.show.default_clip_path``).
DEFAULT_OUT = "results/show/TARGET_DISTORTION_TRAJECTORY_seedN.mp4"


def add_parsers(sub) -> None:
    p = sub.add_parser("show", help="write a clip of one cell's passive and active runs side by side",
                       description="Render the camera's frames of one paper-study cell and replicate, passive "
                                   "left and active right, with the image centre (grey), the true centre and "
                                   "its trace (green, yellow) and the detection (magenta), as MP4 (H.264, plays "
                                   "in a browser) or GIF.")
    p.add_argument("--target", choices=("sphere", "aruco"), default="sphere")
    p.add_argument("--distortion", choices=("none", "default"), default="default")
    p.add_argument("--trajectory", choices=("circular", "diagonal"), default="circular")
    p.add_argument("--seed", type=nonnegative_int, default=0, help="the replicate (default 0)")
    p.add_argument("--config", help="a study TOML (default: the paper's, data/studies/paper.toml)")
    p.add_argument("--store", metavar="DIR", help="results store to reuse runs from and keep them in (default: none; "
                                                  "results/store is the one gimbal-lab run paper fills)")
    p.add_argument("--every", type=positive_int, default=1, help="show every N-th frame (default 1)")
    p.add_argument("--out", metavar="FILE", help=f"the clip, .mp4 or .gif (default {DEFAULT_OUT}, e.g. "
                                                 "results/show/sphere_default_circular_seed0.mp4)")
    p.set_defaults(func=_show_command, _parser=p)


def _show_command(args, parser) -> int:
    from .outputs import OutputError, check_new_file, check_writable_folder

    try:
        if args.out is not None:
            check_new_file(args.out, "--out", suffixes=(".mp4", ".gif"))
        if args.store is not None:
            check_writable_folder(args.store, "--store")
    except OutputError as exc:
        parser.error(str(exc))
    from .show import default_clip_path, show
    from .studies.paper import PaperStudy

    out = Path(args.out) if args.out is not None else default_clip_path(args.target, args.distortion, args.trajectory,
                                                                        args.seed)
    try:
        study = PaperStudy.from_toml(args.config) if args.config else PaperStudy()
        if args.seed not in study.seeds:
            raise ValueError(f"seed must be one of the study's replicates {study.seeds[0]}..{study.seeds[-1]}, "
                             f"got {args.seed!r}")
        path = show(args.target, args.distortion, args.trajectory, args.seed, out, study=study, store=args.store,
                    every=args.every)
    except (ValueError, FileNotFoundError) as exc:  # OutputError is a ValueError
        parser.error(str(exc))
    except KeyboardInterrupt as exc:
        if type(exc) is KeyboardInterrupt:  # a RunInterrupted says what is kept itself
            raise KeyboardInterrupt(f"interrupted: no clip written ({out} is as it was)") from None
        raise
    kind = "H.264 MP4, plays in a browser" if path.suffix.lower() == ".mp4" else "GIF"
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB, {kind})")
    return 0
