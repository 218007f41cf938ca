// A stand-in for Flamenco Manager's job compiler, for tests: runs a job type
// script with the globals the Manager gives it (author.Task, author.Command,
// frameChunker, print, alert) and prints what it authored as JSON.
//
//   node flamenco_job_compiler.js SCRIPT.js '{"frames": "1-10", ...}'
//
// Like the Manager, it fills in the defaults of JOB_TYPE.settings that the
// submitted settings leave out. frameChunker follows the Manager's documented
// behaviour: frames "A-B", "A..B" (Blender notation) or "N", comma-separated,
// sorted and de-duplicated; chunks of at most chunkSize frames, each written
// back in regular notation with runs of three or more frames as "A-B" and
// shorter runs as single frames ("1-4,9,20-22", "9,10").
"use strict";
const fs = require("fs");
const vm = require("vm");

function explode(frameRange) {
    const frames = new Set();
    const whole = (text) => {
        const t = text.trim();
        if (!/^-?[0-9]+$/.test(t)) throw new Error(`invalid range "${frameRange}": ${text}`);
        return parseInt(t, 10);
    };
    for (const part of frameRange.split("..").join("-").split(",")) {
        const ends = part.split("-");
        if (ends.length === 1) {
            frames.add(whole(ends[0]));
        } else if (ends.length === 2) {
            for (let f = whole(ends[0]); f <= whole(ends[1]); f++) frames.add(f);
        } else {
            throw new Error(`invalid range "${frameRange}": ${part}`);
        }
    }
    return [...frames].sort((a, b) => a - b);
}

function merge(frames) {
    const parts = [];
    let start = 0;
    for (let i = 1; i <= frames.length; i++) {
        if (i < frames.length && frames[i] === frames[i - 1] + 1) continue;
        const run = frames.slice(start, i);
        if (run.length >= 3) parts.push(`${run[0]}-${run[run.length - 1]}`);
        else parts.push(...run.map(String));
        start = i;
    }
    return parts.join(",");
}

function frameChunker(frameRange, chunkSize) {
    if (!(chunkSize >= 1)) throw new Error(`invalid chunk size, must be positive number: ${chunkSize}`);
    const frames = explode(String(frameRange).trim());
    if (frames.length === 0) throw new Error("empty range");
    const chunks = [];
    for (let i = 0; i < frames.length; i += chunkSize) chunks.push(merge(frames.slice(i, i + chunkSize)));
    return chunks;
}

const [script, settingsJson] = process.argv.slice(2);
const printed = [];
const sandbox = {
    print: (...args) => printed.push(args.join(" ")),
    alert: (...args) => printed.push(args.join(" ")),
    frameChunker,
    author: {
        Task: (name, type) => ({
            name, type, commands: [], dependencies: [],
            addCommand(cmd) { this.commands.push(cmd); },
            addDependency(task) { this.dependencies.push(task.name); },
        }),
        Command: (name, parameters) => ({ name, parameters }),
    },
};
vm.createContext(sandbox);
vm.runInContext(fs.readFileSync(script, "utf8"), sandbox, { filename: script });
const jobType = vm.runInContext("JOB_TYPE", sandbox);
const settings = {};
for (const s of jobType.settings) if ("default" in s) settings[s.key] = s.default;
Object.assign(settings, JSON.parse(settingsJson));
const tasks = [];
const job = { settings, addTask(task) { tasks.push(task); } };
try {
    sandbox.compileJob(job);
} catch (e) {
    console.log(JSON.stringify({ error: String(e && e.message !== undefined ? e.message : e) }));
    process.exit(1);
}
console.log(JSON.stringify({ jobType, tasks, printed }));
