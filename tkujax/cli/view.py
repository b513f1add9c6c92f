"""`tkujax view DIR`: a sweep's records replayed in the browser (a viser page on --host:--port)."""

from __future__ import annotations

import importlib.util
import sys
import time

from tkujax.cli.errors import bounded_float, bounded_int
from tkujax.cli.shared_options import add_robot_check_option

MAX_SHOWN = 64


def selection_from_args(args):
    """The parsed filter options as a `tkujax.viewer.playback.Selection`."""
    from tkujax.viewer.playback import Selection, parse_band

    return Selection(
        fell=True if args.fell else False if args.survived else None,
        direction=None if args.direction is None else parse_band(args.direction, "--direction"),
        impulse=None if args.impulse is None else parse_band(args.impulse, "--impulse"),
        control=None if args.control is None else args.control == "on",
        indices=tuple(args.index or ()), max_pushes=args.max)


def geom_groups(text: str) -> tuple[int, ...]:
    """'0,1,2' -> (0, 1, 2): MuJoCo geom groups, each in [0, 5]."""
    try:
        groups = tuple(int(g) for g in str(text).split(","))
    except ValueError:
        groups = ()
    if not groups or not all(0 <= g <= 5 for g in groups):
        raise ValueError(f"--geom-groups must be MuJoCo geom groups in [0, 5] separated by "
                         f"commas, got {text!r}")
    return groups


def _cmd_view(args) -> int:
    from tkujax.studies.robot_inputs import sweep_robot
    from tkujax.sweeps.sweep import load
    from tkujax.sweeps.sweep_state import require_complete
    from tkujax.viewer.playback import replay_scenes, select_records

    selection = selection_from_args(args)
    groups = geom_groups(args.geom_groups)
    state = require_complete(args.dir, args.allow_incomplete, "tkujax view")
    if state.mark:
        print(f"{args.dir}: {state.mark}: showing the records of the chunks done",
              file=sys.stderr)
    if importlib.util.find_spec("viser") is None:
        print("tkujax view: error: the viewer needs viser: pip install 'tkujax[view]'",
              file=sys.stderr)
        return 2
    indices = select_records(load(args.dir), selection)
    if not indices:
        raise ValueError(f"no record of {args.dir} matches the filters")

    def progress(i, n, index):
        print(f"replaying record {index} on MuJoCo C ({i + 1}/{n})", file=sys.stderr, flush=True)

    scenes = replay_scenes(args.dir, indices, robot=sweep_robot(args.dir, args.robot),
                           progress=progress, groups=groups)
    from tkujax.viewer.server import ReplayViewer

    viewer = ReplayViewer(scenes, host=args.host, port=args.port)
    try:
        for s in scenes:
            print(s.label.replace("\n", ", "))
        moved = ("" if viewer.server.get_port() == args.port or args.port == 0
                 else f" (port {args.port} was taken)")
        print(f"serving {len(scenes)} replays at {viewer.url}{moved}; Ctrl-C stops", flush=True)
        deadline = None if args.serve_s is None else time.monotonic() + args.serve_s
        while deadline is None or time.monotonic() < deadline:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    return 0


def add_view_command(sub) -> None:
    """view: replay records of a sweep in a browser (viser)."""
    p = sub.add_parser("view", help="replay a sweep's records in the browser: robots side by "
                                    "side, time slider, push arrows, capture points, steps")
    p.add_argument("dir", help="a sweep output folder")
    outcome = p.add_mutually_exclusive_group()
    outcome.add_argument("--fell", action="store_true", help="only records that fell")
    outcome.add_argument("--survived", action="store_true", help="only records that survived")
    p.add_argument("--direction", default=None, metavar="LO,HI",
                   help="azimuth band in degrees (0 = pushed from behind, 90 = from the right; "
                        "315,45 wraps through 0)")
    p.add_argument("--impulse", default=None, metavar="LO,HI", help="impulse band, N s")
    p.add_argument("--control", choices=["on", "off"], default=None,
                   help="only records with the controller on (or off)")
    p.add_argument("--index", type=bounded_int(0, 2**31 - 1), action="append", default=None,
                   metavar="N", help="a record's push_id (repeatable); the filters still apply")
    p.add_argument("--max", type=bounded_int(1, MAX_SHOWN), default=4,
                   help="at most this many records, side by side (default 4; more matching: "
                        "an evenly spaced sample)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default 127.0.0.1: reach it through an ssh port "
                        "forward; 0.0.0.0 serves every interface)")
    p.add_argument("--port", type=bounded_int(0, 65535), default=8080,
                   help="port (default 8080; the next free one when taken; 0: any free port)")
    p.add_argument("--serve-s", type=bounded_float(0.0, 1e7), default=None, metavar="S",
                   help="stop after S seconds (default: serve until Ctrl-C)")
    p.add_argument("--geom-groups", default="0,1,2", metavar="G,G",
                   help="geom groups to draw (default 0,1,2, as MuJoCo's viewer; a robot with "
                        "heavy visual meshes draws lighter with its collision group, often 3)")
    p.add_argument("--allow-incomplete", action="store_true",
                   help="replay records of an incomplete sweep (the chunks done; default: "
                        "refused)")
    add_robot_check_option(p)
    p.set_defaults(func=_cmd_view)
