"""``penumbra farm`` on Dask distributed: one task per chunk of frames.

Each task (``render_chunk``, run on a worker) renders its chunk exactly as
``penumbra render SCENE --frames <chunk> --out DIR ...`` does, in a child
process of the worker (``python -m penumbra.cli``, with ``watchdog.py``), and is retried twice when it
fails. A worker that dies takes its child with it (the child's watchdog) and
the scheduler gives the chunk to another worker; the frames the dead one had
finished are skipped there, the one it was writing was never renamed into
place. Chunks whose frames are all written are not submitted at all, so a
farm run that was killed is finished by running the same command again.

The client follows the files, not the tasks: a frame is done when its JSON
(written last) exists, so the progress bar (frames done / total, rate, time
left: tqdm, on stderr when it is a terminal) counts frames as they land, and
the summary's "written" / "skipped" / "failed" are read from the output
folder. Task keys are a hash of the job and the chunk, so a restarted client
joins a chunk the cluster is still rendering for its predecessor.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

from tqdm import tqdm

from ..core.output import output_paths
from . import watchdog
from .chunks import chunk_frames, frame_spec

RETRIES = 2
POLL_S = 0.5
CONNECT_TIMEOUT = "10s"
#: the child: the command line itself, as a module (``python -m penumbra.cli``)
CHILD_MODULE = f"{__package__.rsplit('.', 1)[0]}.cli"
ERROR_LINES = 3


class FarmInputError(ValueError):
    """Bad input found by the farm (unreachable scheduler, a chunk's render
    exiting 2): one line for the user, exit status 2."""


class ChunkFailed(RuntimeError):
    """A chunk's render exited with an error; Dask retries the task."""


@dataclass(frozen=True)
class FarmJob:
    scene: str                      # absolute path, the same on every worker
    out: str                        # absolute path, the same on every worker
    frames: Tuple[int, ...]
    chunk_size: int
    render_options: Tuple[str, ...] = ()
    force: bool = False

    @property
    def stem(self) -> str:
        return os.path.splitext(os.path.basename(self.scene))[0]

    def render_argv(self, chunk: Sequence[int]) -> List[str]:
        """``penumbra render`` arguments for one chunk."""
        return [self.scene, "--frames", frame_spec(chunk), "--out", self.out, *self.render_options]

    def key(self, chunk: Sequence[int]) -> str:
        job = json.dumps([self.scene, self.out, list(self.render_options)]).encode()
        return f"penumbra-render-{self.stem}-{frame_spec(chunk)}-{hashlib.sha1(job).hexdigest()[:12]}"


def _last_lines(text: str, n: int = ERROR_LINES) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return " | ".join(lines[-n:]) if lines else "(no output)"


def render_chunk(render_argv: Sequence[str]) -> dict:
    """The Dask task: ``penumbra render <render_argv>`` in a child process.

    Returns ``{"seconds": ...}``, or ``{"bad_input": line}`` when the render
    refused its input (exit 2: retrying would not help); raises ChunkFailed
    (so Dask retries) on any other failure.
    """
    t0 = time.perf_counter()
    env = dict(os.environ, **{watchdog.ENV: "1"})
    proc = subprocess.run([sys.executable, "-m", CHILD_MODULE, "render", *render_argv],
                          stdin=subprocess.DEVNULL, capture_output=True, text=True, env=env)
    if proc.returncode == 2:
        return {"bad_input": _last_lines(proc.stderr, 1).removeprefix("penumbra: error: ")}
    if proc.returncode != 0:
        raise ChunkFailed(f"penumbra render exited {proc.returncode}: {_last_lines(proc.stderr)}")
    return {"seconds": time.perf_counter() - t0}


def _mtime(path: str) -> Optional[int]:
    try:
        return os.stat(path).st_mtime_ns
    except FileNotFoundError:
        return None


def _complete(json_path: str) -> bool:
    """The frame's JSON exists and so does the EXR it names."""
    try:
        with open(json_path) as f:
            exr_name = json.load(f).get("exr")
    except (OSError, ValueError):
        return False
    return exr_name is None or os.path.exists(os.path.join(os.path.dirname(json_path), exr_name))


@contextlib.contextmanager
def _client(scheduler: Optional[str], workers: Optional[int]):
    from distributed import Client, LocalCluster
    if scheduler:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, ValueError, TimeoutError) as exc:
            raise FarmInputError(f"cannot reach the Dask scheduler at {scheduler}: "
                                 f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__}")
        with client:
            yield client
        return
    # no dashboard; the scheduler's HTTP server (health routes) on a free port, not 8787
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client


def run_farm(job: FarmJob, scheduler: Optional[str] = None, workers: Optional[int] = None,
             quiet: bool = False) -> int:
    """Render ``job`` on the cluster; print the summary. 0 when every frame
    exists, 1 when some failed, 2 when a chunk's render refused its input."""
    t0 = time.perf_counter()
    json_of = {f: output_paths(job.out, job.stem, f)["json"] for f in job.frames}
    before = {f: _mtime(p) for f, p in json_of.items()}

    def landed(f):   # written by this run (with --force: rewritten)
        m = _mtime(json_of[f])
        return m is not None and (before[f] is None or (job.force and m != before[f]))

    def done(f):
        return landed(f) or (before[f] is not None and not job.force)

    chunks = chunk_frames(job.frames, job.chunk_size)
    todo = [c for c in chunks if not all(done(f) for f in c)]
    results: Dict[str, dict] = {}
    errors: Dict[str, str] = {}
    n_workers = 0
    if todo:
        with _client(scheduler, workers) as client:
            n_workers = len(client.scheduler_info().get("workers", {}))
            if not n_workers:
                print(f"penumbra farm: no worker has joined {scheduler} yet; the chunks wait for one",
                      file=sys.stderr)
            futures = [(frame_spec(c), client.submit(render_chunk, job.render_argv(c), key=job.key(c),
                                                     retries=RETRIES)) for c in todo]
            bar = tqdm(total=len(job.frames), initial=sum(done(f) for f in job.frames), unit="frame",
                       desc="penumbra farm", file=sys.stderr, disable=quiet or not sys.stderr.isatty())
            while True:
                finished = all(fut.done() for _, fut in futures)
                bar.update(sum(done(f) for f in job.frames) - bar.n)
                if finished:
                    break
                time.sleep(POLL_S)
            bar.close()
            for spec, fut in futures:
                if fut.status == "finished":
                    results[spec] = fut.result()
                else:
                    exc = fut.exception() if fut.status == "error" else None
                    errors[spec] = _last_lines(str(exc), ERROR_LINES) if exc is not None else fut.status
    return _report(job, chunks, landed, before, results, errors, n_workers, time.perf_counter() - t0)


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _report(job, chunks, landed, before, results, errors, n_workers, seconds) -> int:
    written = [f for f in job.frames if landed(f)]
    skipped = [f for f in job.frames if not job.force and before[f] is not None and not landed(f)]
    bad_input = [r["bad_input"] for r in results.values() if "bad_input" in r]
    failed = []                                     # (missing frames of a chunk, why)
    for c in chunks:
        spec = frame_spec(c)
        missing = [f for f in c if f not in skipped and not
                   (f in written and _complete(output_paths(job.out, job.stem, f)["json"]))]
        if missing:
            why = errors.get(spec) or (f"bad input: {bad_input[0]}" if bad_input else "not written")
            failed.append((missing, why))
    on = f" on {_plural(n_workers, 'worker')}" if n_workers else ""
    n_failed = sum(len(m) for m, _ in failed)
    print(f"penumbra farm: {_plural(len(job.frames), 'frame')} in {_plural(len(chunks), 'chunk')}{on}: "
          f"{len(written)} written, {len(skipped)} skipped (already there), {n_failed} failed ({seconds:.1f} s)")
    for missing, why in failed:
        print(f"  failed {frame_spec(missing)}: {why}")
    if bad_input:
        raise FarmInputError(bad_input[0])
    return 0 if not failed else 1
