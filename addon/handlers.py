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
render, ``bridge.capture.is_capturing()``, and the Cycles reference
renders, ``bridge.cycles_reference.is_rendering()``). Errors never stop the render: each
prints one ``Penumbra: ...`` line and is kept in :data:`state`.
Per-light settings apply as in Compute Passes; the Cycles reference is
skipped inside a render (it needs a render of its own).

``register`` also installs ``bridge.buffer_cache``'s depsgraph handler,
which tells the Preview when its kept camera G-buffer is stale.
"""
from __future__ import annotations

import sys
from typing import Optional

import bpy
from bpy.app.handlers import persistent

from ..bridge import buffer_cache, compat, settings
from ..bridge.capture import is_capturing
from ..bridge.cycles_reference import is_rendering
from ..bridge.pipeline import (FrameRequest, NoCamera, check_out_dir, compute_frame, finish_frame, first_line,
                               render_output_folder)

#: what the running render has done: frames computed, files written, errors
state = {"active": False, "scene": None, "done": set(), "written": [], "errors": [], "notes": []}


def _reset(active: bool, scene_name: Optional[str] = None):
    state.update(active=active, scene=scene_name, done=set(), written=[], errors=[], notes=[])


def _capturing() -> bool:
    """Penumbra's own renders (the capture render, the Cycles reference
    renders) are not the user's: the handlers leave them alone."""
    return is_capturing() or is_rendering()


def _enabled(scene) -> bool:
    s = settings.scene_settings(scene)
    return s is not None and bool(s.render_passes)


def _report(msg: str):
    state["errors"].append(msg)
    print(f"Penumbra: {msg}", file=sys.stderr)


def compute_render_frame(scene, depsgraph=None):
    """Compute, store and write the passes of ``scene``'s current frame.
    Returns the written paths, or None (reason in ``state``)."""
    frame = int(scene.frame_current)
    out_dir, err = check_out_dir(render_output_folder(scene, frame))
    if err:
        _report(f"frame {frame}: {err}")
        return None
    request = FrameRequest.from_scene_settings(depsgraph=depsgraph,
                                               mode="AUTO" if depsgraph is not None else "VIEWPORT",
                                               in_render=True, skip_deleted=False)
    try:
        job = compute_frame(scene, request)
    except NoCamera as exc:
        _report(f"frame {frame}: {exc}")
        return None
    state["notes"] = list(job.notes)
    _result, paths = finish_frame(scene, job, out_dir)
    for w in job.warnings:
        _report(f"frame {frame}: {w}")
    if paths is None:
        state["notes"].append(f"frame {frame}: no light to compute, nothing written")
        return None
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
        _report(f"frame {frame}: {type(exc).__name__}: {first_line(exc)}")


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
    buffer_cache.watch()          # the Preview's kept buffers follow the depsgraph
    _reset(False)


def unregister():
    _remove_ours()
    buffer_cache.unwatch()
    _reset(False)
