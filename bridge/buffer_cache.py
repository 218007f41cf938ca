"""The Preview's frame cache kept from one Preview to the next.

While the camera and the geometry do not change, a Preview takes over the
last one's camera G-buffer, BVHs and the views and passes of the lights that
did not move (``core.frame_cache.FrameCache``): moving a light
re-computes only its light view and the filter, and a light whose shape,
place and method settings did not change is not computed again.

What changed is the depsgraph's to say: :func:`on_depsgraph_update`
(``bpy.app.handlers.depsgraph_update_post``; :func:`watch` installs it)
bumps a generation counter on every update that is not a light's (a light
object's transform or geometry, its Light data), Penumbra's own images or
the scene itself; loading a file and undo / redo drop the cache. A kept
entry is used only while its generation is the current one and the capture
matches it: scene, frame, resolution, camera (``raycast.camera_params``)
and triangles, flags and object ids (compared, a few ms even for a large
scene). Nothing is kept while the handler is not installed.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Optional

import bpy
import numpy as np
from bpy.app.handlers import persistent

#: images Penumbra writes (a Preview's own write-back must not invalidate it)
OWN_IMAGE_PREFIX = "Penumbra "

_lock = threading.Lock()
_generation = 0


@dataclass
class Ticket:
    """What a Preview's capture was checked against; ``store`` keeps its
    cache only under the generation it was prepared in."""
    key: tuple
    generation: int
    captured: object


@dataclass
class _Entry:
    ticket: Ticket
    cache: object


_entry: Optional[_Entry] = None


def _ignored(update) -> bool:
    """Updates that change neither the camera's view nor any triangle."""
    ob = update.id
    if isinstance(ob, bpy.types.Object):
        return ob.type == "LIGHT"
    if isinstance(ob, (bpy.types.Light, bpy.types.Scene)):
        return True
    if isinstance(ob, bpy.types.Image):
        return ob.name.startswith(OWN_IMAGE_PREFIX)
    return False


def invalidate() -> None:
    """Forget the kept cache (the next Preview builds its buffers anew)."""
    global _generation, _entry
    with _lock:
        _generation += 1
        _entry = None


@persistent
def on_depsgraph_update(scene, depsgraph=None):
    """depsgraph_update_post: anything but a light, the scene or our own
    images changed -> the kept cache is stale."""
    if depsgraph is None:
        invalidate()
        return
    if not all(_ignored(u) for u in depsgraph.updates):
        invalidate()


@persistent
def on_reload(*_args):
    """load_post / undo_post / redo_post: the data was replaced."""
    invalidate()


HANDLERS = (("depsgraph_update_post", on_depsgraph_update), ("load_post", on_reload),
            ("undo_post", on_reload), ("redo_post", on_reload))


def _ours(fn):
    return lambda h: getattr(h, "__name__", "") == fn.__name__ and getattr(h, "__module__", "") == fn.__module__


def watching() -> bool:
    return any(_ours(on_depsgraph_update)(h) for h in bpy.app.handlers.depsgraph_update_post)


def watch() -> None:
    """Install the handlers (once; the add-on's register and the first
    Preview call it)."""
    for attr, fn in HANDLERS:
        lst = getattr(bpy.app.handlers, attr)
        if not any(_ours(fn)(h) for h in lst):
            lst.append(fn)


def unwatch() -> None:
    """Remove the handlers and forget the cache (the add-on's unregister)."""
    for attr, fn in HANDLERS:
        lst = getattr(bpy.app.handlers, attr)
        for h in [h for h in lst if _ours(fn)(h)]:
            lst.remove(h)
    invalidate()


def _key(scene, captured) -> tuple:
    from ..core import raycast
    W, H = captured.resolution
    cam = raycast.camera_params(captured.camera, W, H).tobytes()
    return (scene.name, int(captured.frame), (int(W), int(H)), cam, captured.geometry_counts(),
            captured.is_flattened)


def _same_geometry(a, b) -> bool:
    """The two captures hold the same geometry and flags: compared as
    instances (meshes, placements, objects) while neither is flattened, so
    a scatter is never flattened to be compared, else triangle by triangle."""
    if (a.alpha is None) != (b.alpha is None):
        return False
    if not a.is_flattened and not b.is_flattened:
        ia, ib = a.instances, b.instances
        flags = [[(o.casts_shadow, o.visible_camera) for o in s.objects] for s in (a, b)]
        return (flags[0] == flags[1] and len(ia.faces) == len(ib.faces)
                and all(np.array_equal(x, y) for x, y in zip(ia.vertices + ia.faces, ib.vertices + ib.faces))
                and all(np.array_equal(getattr(ia, n), getattr(ib, n))
                        for n in ("mesh", "world_from_mesh", "object_id")))
    return all(np.array_equal(getattr(a, n), getattr(b, n))
               for n in ("triangles", "tri_object", "tri_casts_shadow", "tri_visible_camera"))


def ticket(scene, captured) -> Optional[Ticket]:
    """The ticket of a Preview about to run on ``captured`` (None: no camera,
    or the handler is not installed)."""
    if captured.camera is None or not watching():
        return None
    return Ticket(_key(scene, captured), _generation, captured)


def lookup(t: Optional[Ticket]):
    """The kept cache when it was built for the same capture under the
    current generation, else None."""
    e = _entry
    if t is None or e is None or e.ticket.generation != _generation or t.generation != _generation:
        return None
    if e.ticket.key != t.key or not _same_geometry(e.ticket.captured, t.captured):
        return None
    return e.cache


def store(t: Optional[Ticket], cache) -> None:
    """Keep ``cache`` (a core FrameCache) for the next Preview unless something changed since
    ``t`` was taken."""
    global _entry
    if t is None or cache is None:
        return
    with _lock:
        if t.generation == _generation:
            _entry = _Entry(t, cache)
