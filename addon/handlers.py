"""Passes in every render: render handlers that compute each rendered
frame's passes before compositing, store them as the ``Penumbra <layer>
<pass>`` images the compositor nodes show, and write the frame's EXR + JSON
(DESIGN.md naming, ``core.output.write_frame``) beside the render output
(``scene.render.frame_path``'s folder) or into the scene's output folder.

Enabled by ``scene.penumbra.render_passes`` (off by default, so plain renders
are not slowed). Order of the handlers for each frame, checked in bpy 5.0.1
(``render(animation=True)`` and still renders alike): render_init once, then
per frame render_pre(scene, None), frame_change_post(scene, render depsgraph),
the render, compositing, render_post, render_write. The passes are computed
in frame_change_post, from the render depsgraph. When the compositor has no
Render Layers node Blender renders nothing and frame_change_post does not
run; then render_pre computes them from the view layer's depsgraph.

Each handler returns at once during Penumbra's own renders (the capture
render, ``operators.capture.is_capturing()``, and the Cycles reference
renders, ``operators.cycles_reference.is_rendering()``). Errors never stop the render: each
prints one ``Penumbra: ...`` line and is kept in :data:`state`.
Per-light settings apply as in Compute Passes; the Cycles reference is
skipped inside a render (it needs a render of its own).
"""
from __future__ import annotations

import os
import sys
from typing import Optional

import bpy
from bpy.app.handlers import persistent

from ..bridge import compat

from . import properties as props

#: what the running render has done: frames computed, files written, errors
state = {"active": False, "scene": None, "done": set(), "written": [], "errors": [], "notes": []}


def _reset(active: bool, scene_name: Optional[str] = None):
    state.update(active=active, scene=scene_name, done=set(), written=[], errors=[], notes=[])


def _capturing() -> bool:
    """Penumbra's own renders (the capture render, the Cycles reference
    renders) are not the user's: the handlers leave them alone."""
    from ..operators.capture import is_capturing
    if is_capturing():
        return True
    try:
        from ..operators.cycles_reference import is_rendering
    except ImportError:
        return False
    return is_rendering()


def _enabled(scene) -> bool:
    s = props.scene_settings(scene)
    return s is not None and bool(s.render_passes)


def _report(msg: str):
    state["errors"].append(msg)
    print(f"Penumbra: {msg}", file=sys.stderr)


def output_folder(scene, frame: int) -> str:
    """Where a render's frame files go: the scene's output folder if set, else
    the render output's folder (a ``penumbra`` sub-folder if the render's
    own file would have the name Penumbra's EXR has)."""
    s = props.scene_settings(scene)
    if s is not None and s.output_folder.strip():
        return s.output_folder.strip()
    frame_path = bpy.path.abspath(scene.render.frame_path(frame=frame))
    folder = os.path.dirname(frame_path) or os.getcwd()
    from ..core.output import output_paths
    from ..operators.capture import blend_stem
    if os.path.abspath(output_paths(folder, blend_stem(scene), frame)["exr"]) == os.path.abspath(frame_path):
        folder = os.path.join(folder, "penumbra")
    return folder


def compute_render_frame(scene, depsgraph=None):
    """Compute, store and write the passes of ``scene``'s current frame.
    Returns the written paths, or None (reason in ``state``)."""
    from ..core.output import write_frame
    from ..operators import compute
    from ..operators.capture import capture_scene
    from .preferences import apply_threads
    frame = int(scene.frame_current)
    out_dir, err = compute.check_out_dir(output_folder(scene, frame))
    if err:
        _report(f"frame {frame}: {err}")
        return None
    if depsgraph is not None:
        captured = capture_scene(scene, depsgraph=depsgraph)
    else:
        captured = capture_scene(scene, mode="VIEWPORT")
    if captured.camera is None:
        _report(f"frame {frame}: the scene has no camera")
        return None
    jobs, notes = compute.light_jobs(scene, captured)
    all_passes = [p for j in jobs for p in j.passes]
    _ext, ext_notes = compute.external_producers(scene, captured, all_passes, in_render=True)
    for j in jobs:
        j.passes = [p for p in j.passes if p != "cycles"] or [compute.resolve_method(None)]
    state["notes"] = notes + ext_notes
    apply_threads()
    results = [compute.run_step(captured, st) for st in compute.make_steps(jobs, per_light=False)]
    result = compute.merge_results(captured, results) if results else compute.empty_result(captured)
    compute.store_images(result)
    if not result.lights:
        state["notes"].append(f"frame {frame}: no light to compute, nothing written")
        return None
    paths = write_frame(result, out_dir, previews=False)
    state["written"].append(paths)
    return paths


def _run(scene, depsgraph):
    frame = int(scene.frame_current)
    if frame in state["done"]:
        return
    state["done"].add(frame)
    try:
        compute_render_frame(scene, depsgraph)
    except Exception as exc:              # never a traceback in the middle of a render
        text = str(exc).strip().splitlines()
        _report(f"frame {frame}: {type(exc).__name__}: {text[-1] if text else ''}")


# --------------------------------------------------------------------------
# handlers
@persistent
def penumbra_render_init(scene, _=None):
    if _capturing():
        return
    _reset(_enabled(scene), scene.name)
    if state["active"]:
        scene.render.use_lock_interface = True


@persistent
def penumbra_render_pre(scene, _=None):
    if _capturing() or not state["active"] or scene.name != state["scene"]:
        return
    state["done"].discard(int(scene.frame_current))       # a new frame (or a re-render of it)
    if not _renders_layers(scene):
        _run(scene, None)


@persistent
def penumbra_frame_change_post(scene, depsgraph=None):
    if _capturing() or not state["active"] or scene.name != state["scene"]:
        return
    if depsgraph is None or depsgraph.mode != "RENDER":
        return
    _run(scene, depsgraph)


@persistent
def penumbra_render_end(scene, _=None):
    if _capturing():
        return
    state["active"] = False


@persistent
def penumbra_load_post(*_args):
    for scene in bpy.data.scenes:
        if _enabled(scene):
            scene.render.use_lock_interface = True


def _renders_layers(scene) -> bool:
    """Whether Blender renders the scene (so frame_change_post will get the
    render depsgraph): not when the compositor is on and has no Render
    Layers node (then Blender only composites)."""
    trees = compat.render_trees(scene)
    if not trees or not scene.render.use_compositing:
        return True
    seen = set()

    def has_rlayers(t, top):
        if t.as_pointer() in seen:
            return False
        seen.add(t.as_pointer())
        for n in t.nodes:
            if n.bl_idname == "CompositorNodeRLayers" or (top and n.bl_idname in compat.RENDER_INPUT_NODES):
                return True
            sub = getattr(n, "node_tree", None)
            if sub is not None and has_rlayers(sub, False):
                return True
        return False
    return any(has_rlayers(t, True) for t in trees)


HANDLERS = (
    ("render_init", penumbra_render_init),
    ("render_pre", penumbra_render_pre),
    ("frame_change_post", penumbra_frame_change_post),
    ("render_complete", penumbra_render_end),
    ("render_cancel", penumbra_render_end),
    ("load_post", penumbra_load_post),
)


def _remove_ours():
    for attr, fn in HANDLERS:
        lst = getattr(bpy.app.handlers, attr)
        for h in [h for h in lst if getattr(h, "__name__", "") == fn.__name__
                  and getattr(h, "__module__", "") == fn.__module__]:
            lst.remove(h)


def register():
    _remove_ours()
    for attr, fn in HANDLERS:
        getattr(bpy.app.handlers, attr).append(fn)
    _reset(False)


def unregister():
    _remove_ours()
    _reset(False)
