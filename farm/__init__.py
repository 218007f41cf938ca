"""Penumbra on a render farm: three routes to the same per-chunk command,
``penumbra render SCENE.blend --frames <chunk> --out DIR ...``.

- ``flamenco/penumbra_render.js``: a Flamenco custom job type (one task per
  ``frameChunker`` chunk, an ``exec`` command running ``{penumbra}``);
- ``openjd/penumbra-render.yaml``: an Open Job Description template (AWS
  Deadline Cloud) with TASK_CHUNKING, one ``CHUNK[INT]`` task per chunk;
- ``penumbra farm``: Dask distributed (``dask_farm.py``), one task per chunk
  on an existing scheduler or a LocalCluster, each rendering its chunk in a
  child process of the worker (``python -m penumbra.cli``; ``watchdog.py`` ends it with its worker).

Every route leans on what ``penumbra render`` already guarantees: each frame
is written atomically (JSON last, so the JSON marks a finished frame), frames
already written are skipped, and SIGTERM interrupts cleanly. A chunk that is
run twice, or killed and run again elsewhere, loses and duplicates nothing.
Nothing here imports bpy: only the child processes do.
"""
