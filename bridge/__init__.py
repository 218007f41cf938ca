"""Blender <-> core: the Blender-side bridge (imports bpy; never imports addon/, operators/ or cli)."""
