"""Options shared by several commands: the robot model (--model), the parameter file
(--params), the backend and multi-process options."""

from __future__ import annotations

import argparse

from tkujax.cli.errors import bounded_int

# Processes of one sweep (tkujax.sweeps.sweep_folder.MAX_PROCESSES) and chunks of one run.
MAX_PROCESSES = 65_536
MAX_CHUNKS = 1 << 30

RENDER_HELP = ("Install EGL (apt-get install libegl1 libgl1-mesa-dri) and set MUJOCO_GL=egl, or "
               "OSMesa (apt-get install libosmesa6) and MUJOCO_GL=osmesa.")


def read_named(option: str, path, loader):
    """`loader(path)`, a file that is not UTF-8 named with its option (a ValueError)."""
    try:
        return loader(path)
    except UnicodeDecodeError as err:
        raise ValueError(f"{option} {path}: not UTF-8 text (byte {err.start}); JSON files are "
                         "UTF-8") from None


def model_params_from_options(items: list[str], variant: str = "calibrated"):
    """--model: a model_params.json file (tkujax calibrate output) and/or KEY=VALUE overrides,
    applied in order to the variant's model; None when none is given (the variant's default)."""
    import dataclasses

    from tkujax.model import ModelParams
    from tkujax.model.params_json import load_model_params_json

    if not items:
        return None
    mp = ModelParams.estimated() if variant == "estimated" else ModelParams()
    for item in items:
        if item.endswith(".json"):
            mp = read_named("--model", item, load_model_params_json)
        else:
            over = ModelParams.from_overrides([item])      # validates the key and the number
            key = item.split("=", 1)[0].strip()
            mp = dataclasses.replace(mp, **{key: getattr(over, key)}).validate()
    return mp


def policy_from_option(path: str | None):
    """--params: (ControllerParams, Schedule or None) of a parameter or policy file, or
    (None, None) when none is given."""
    from tkujax.control.params_files import load_policy_json

    return read_named("--params", path, load_policy_json) if path else (None, None)


def controller_params_from_option(path: str | None):
    """--params of the commands that take plain controller parameters: ControllerParams or
    None."""
    from tkujax.control.params_files import load_controller_params_json

    return read_named("--params", path, load_controller_params_json) if path else None


def add_parallel_options(p: argparse.ArgumentParser) -> None:
    """--backend and the multi-process options of the sweep-running commands."""
    p.add_argument("--backend", choices=["auto", "mjx", "mujoco"], default="auto",
                   help="auto: MJX on a GPU, MuJoCo C on a CPU when the spec allows it")
    p.add_argument("--process-id", type=bounded_int(0, MAX_PROCESSES - 1), default=None,
                   help="multi-process: this process, in [0, --num-processes)")
    p.add_argument("--num-processes", type=bounded_int(1, MAX_PROCESSES), default=None,
                   help="multi-process: how many")
    p.add_argument("--coordinator", default=None, help="multi-process: HOST:PORT of process 0")


def add_robot_check_option(p: argparse.ArgumentParser) -> None:
    """--robot of the commands that read sweeps: the robot file the sweep ran on."""
    p.add_argument("--robot", default=None, metavar="FILE.toml",
                   help="the robot file the sweep ran on (checked against the sha256 its "
                        "manifest records; default: the manifest's path)")


def parallel_kwargs(args) -> dict:
    """The parsed parallel options as keyword arguments of run_sweep / run_capture."""
    return dict(process_id=args.process_id, num_processes=args.num_processes,
                coordinator=args.coordinator, backend=args.backend)
