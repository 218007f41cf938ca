"""``penumbra farm SCENE.blend --frames SPEC [--chunk N] (--scheduler URL |
--workers N) [render options]``: the subcommand's arguments and its entry.

The render options are those of ``penumbra render``, taken from its parser
(same names, same checks, same one-line errors) and forwarded to every chunk
as the user typed them. Imports nothing heavy: Dask is loaded only when the
command runs, and bpy never (the chunks' child processes load it).
"""
from __future__ import annotations

import argparse
import os
from typing import List

DEFAULT_CHUNK = 10
# render options that the farm sets per chunk, or that make no sense for a farm
_NOT_FORWARDED = ("help", "scene", "frame", "frames", "out", "quiet")   # farm has its own --quiet


def _whole(name: str, lo: int, hi: int):
    def conv(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}")
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"{name} must be {lo}..{hi}, got {v}")
        return v
    return conv


def _checked_text(convert):
    """Check a value with the render parser's own conversion, keep the text."""
    def conv(text: str) -> str:
        convert(text)
        return text
    return conv


def add_farm_parser(sub) -> None:
    """Add ``farm`` to the subparsers ``sub``, after ``render``."""
    render = sub.choices["render"]
    f = sub.add_parser("farm", help="render a frame range in chunks on Dask (a scheduler, or local workers)",
                       description="One Dask task per chunk of --frames; each runs `penumbra render --frames "
                                   "<chunk>` in a child process of its worker, retried twice if it fails.")
    f.add_argument("scene", help="the .blend file, at the same path on every worker (never modified)")
    f.add_argument("--frames", required=True, type=render._option_string_actions["--frames"].type,
                   help="frames, e.g. 1-250, 1-250:5 or 1,5,9; frames already written are skipped")
    f.add_argument("--chunk", type=_whole("--chunk", 1, 100_000), default=DEFAULT_CHUNK,
                   help=f"frames per task (default: {DEFAULT_CHUNK})")
    where = f.add_mutually_exclusive_group(required=True)
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="an existing Dask scheduler")
    where.add_argument("--workers", type=_whole("--workers", 1, 1024),
                       help="start a local cluster of N worker processes instead")
    f.add_argument("--quiet", action="store_true", help="no progress bar")
    f.add_argument("--out", default=render.get_default("out"),
                   help=f"output folder, at the same path on every worker (default: {render.get_default('out')})")
    forwarded = []
    for a in render._actions:
        if not a.option_strings or a.dest in _NOT_FORWARDED:
            continue
        if a.nargs == 0:
            f.add_argument(*a.option_strings, dest=a.dest, action="store_true", help=a.help)
        else:
            f.add_argument(*a.option_strings, dest=a.dest, default=None, help=a.help, metavar=a.metavar,
                           choices=a.choices, type=_checked_text(a.type) if a.type else None)
        forwarded.append((a.option_strings[-1], a.dest, a.nargs == 0))
    f.set_defaults(farm_parser=f, farm_forwarded=tuple(forwarded))


def render_options(args) -> List[str]:
    """The render options given to ``penumbra farm``, as ``penumbra render`` takes them."""
    argv = []
    for option, dest, flag in args.farm_forwarded:
        value = getattr(args, dest)
        if flag and value:
            argv.append(option)
        elif not flag and value is not None:
            argv += [option, value]
    return argv


def cmd_farm(args) -> int:
    fail = args.farm_parser.error       # one line on stderr, exit 2 (penumbra's parser)
    try:
        from .dask_farm import FarmInputError, FarmJob, run_farm
    except ImportError as exc:
        fail(f"penumbra farm needs Dask distributed and tqdm ({exc.name} is not installed): "
             "pip install 'penumbra[farm]'")
    scene = os.path.abspath(args.scene)
    if not os.path.isfile(scene):
        fail(f"no such file: {args.scene}")
    if not os.access(scene, os.R_OK):
        fail(f"cannot read {args.scene}")
    out = os.path.abspath(args.out)
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as exc:
        fail(f"cannot create output folder {out}: {exc.strerror}")
    if not os.access(out, os.W_OK):
        fail(f"output folder is not writable: {out}")
    job = FarmJob(scene=scene, out=out, frames=tuple(args.frames), chunk_size=args.chunk,
                  render_options=tuple(render_options(args)), force=bool(args.force))
    try:
        return run_farm(job, scheduler=args.scheduler, workers=args.workers, quiet=args.quiet)
    except FarmInputError as exc:
        fail(str(exc))
