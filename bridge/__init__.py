"""Blender <-> core: everything that turns a Blender scene into core's
inputs and core's results back into Blender.

``capture`` (the one bpy -> numpy boundary, and Blender light -> core
Light), ``settings`` (the Penumbra settings read into core requests),
``jobs`` (per-light work and steps), ``pipeline`` (one ``compute_frame``
for the command line, Compute Passes, Preview and the render handler),
``images`` and ``compositor`` (the write-back), ``cycles_reference`` (the
Cycles pass), ``mattes`` (alpha mattes from materials), ``buffer_cache``
(the Preview's kept frame cache), ``compat`` (the Blender 5.0-5.3
differences). Its modules import bpy; it never imports ``addon``,
``operators`` or ``cli``, which all import it (``core`` <- bridge <- UI / CLI).
"""
