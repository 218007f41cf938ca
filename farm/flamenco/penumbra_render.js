// SPDX-License-Identifier: GPL-3.0-or-later
//
// Penumbra soft-shadow passes as a Flamenco custom job type.
//
// Install: copy this file into the `scripts/` folder next to the
// flamenco-manager executable and restart the Manager; define the variable
// `penumbra` in flamenco-manager.yaml (the program each Worker runs: the pip
// install's console script, or a wrapper running `blender --command penumbra`),
// and add `penumbra` to `task_types` in each Worker's flamenco-worker.yaml.
//
// One task per chunk of frameChunker(frames, chunk_size), each with one `exec`
// command: {penumbra} render <blendfile> --frames <chunk> --out <out_dir> ...
// `penumbra render` writes every frame atomically and skips frames already
// written, so a task that is requeued (a Worker died, a task was re-run)
// only computes the frames still missing.

const JOB_TYPE = {
    label: "Penumbra Shadow Passes",
    description: "Soft-shadow passes (a multilayer EXR and a JSON per frame) with `penumbra render`, in chunks of frames",
    settings: [
        { key: "frames", type: "string", required: true,
          eval: "f'{C.scene.frame_start}-{C.scene.frame_end}'",
          evalInfo: { showLinkButton: true, description: "Scene frame range" },
          description: "Frames to compute, e.g. '47', '1-30', '3, 5-10, 47-327'" },
        { key: "chunk_size", type: "int32", default: 10, visible: "submission",
          description: "Frames per task (one `penumbra render` run)" },
        { key: "out_dir", type: "string", subtype: "dir_path", required: true,
          description: "Folder for <blend name>.<frame>.exr / .json, on the shared storage" },
        { key: "methods", type: "string", default: "auto",
          description: "Method ids, comma-separated, 'all', or 'auto' (picked per light)" },
        { key: "resolution", type: "string", default: "",
          description: "WxH, e.g. 1920x1080; empty: the scene's own resolution" },
        { key: "pixel_filter", type: "string", default: "scene",
          description: "How passes are filtered over each pixel: 'scene' (like the scene's render), 'none' " +
                       "(pixel centres), 'box:W', 'gaussian:W' or 'blackman-harris:W' (W in pixels)" },

        // Automatically evaluated settings:
        { key: "blendfile", type: "string", required: true, visible: "web",
          description: "Path of the Blend file to compute" },
    ]
};

function compileJob(job) {
    const settings = job.settings;
    const options = renderOptions(settings);
    for (const chunk of frameChunker(settings.frames, settings.chunk_size)) {
        const task = author.Task(`penumbra-${chunk}`, "penumbra");
        task.addCommand(author.Command("exec", {
            exe: "{penumbra}",
            args: ["render", settings.blendfile, "--frames", chunk, "--out", settings.out_dir].concat(options),
        }));
        job.addTask(task);
    }
}

// The options every chunk shares. An empty resolution is the scene's own,
// an empty pixel filter the scene's render filter.
const PIXEL_FILTER = /^(none|scene(:[0-9]+)?|(box|gaussian|blackman-harris):[0-9]*\.?[0-9]+(:[0-9]+)?)$/;

function renderOptions(settings) {
    const options = ["--methods", (settings.methods || "auto").trim() || "auto"];
    const pixelFilter = (settings.pixel_filter || "").trim().toLowerCase() || "scene";
    if (!PIXEL_FILTER.test(pixelFilter)) {
        throw new Error(`pixel_filter must be scene, none, box:W, gaussian:W or blackman-harris:W, not "${pixelFilter}"`);
    }
    options.push("--pixel-filter", pixelFilter);
    const resolution = (settings.resolution || "").trim();
    if (resolution) {
        if (!/^[0-9]+x[0-9]+$/i.test(resolution)) {
            throw new Error(`resolution must be WxH (e.g. 1920x1080) or empty, not "${resolution}"`);
        }
        options.push("--resolution", resolution);
    }
    return options;
}
