// Run a Flamenco job compiler script outside Flamenco and print the tasks it builds, as JSON.
//
//     node tools/farm/flamenco_harness.js JOB_TYPE.js SETTINGS.json [METADATA.json]
//
// Provides only the documented job-compiler API surface (Flamenco's "Job Compiler Scripts" docs and its
// built-in scripts): the globals `author.Task(name, type)` (→ `addCommand`, `addDependency`),
// `author.Command(type, parameters[, totalFrames])`, `print`, `path` (join, dirname, basename, stem) and the
// `job` argument (`settings`, `metadata`, `addTask`).  Anything else a script touches is an error, as are
// settings that break the script's own JOB_TYPE (unknown keys, missing required ones, values outside
// `choices`), commands of a type Flamenco's worker does not have, and parameters a command does not take.
// Defaults from JOB_TYPE are filled in, as the Manager does.  Output: {"job_type", "settings", "tasks":
// [{"name", "type", "commands": [{"type", "parameters"}], "dependencies": [task names]}]}.
"use strict";

const fs = require("fs");
const nodePath = require("path");
const vm = require("vm");

// Flamenco worker commands and the parameters each takes (internal/worker/command_*.go).
const WORKER_COMMANDS = {
    "blender-render": ["exe", "exeArgs", "argsBefore", "blendfile", "args"],
    "exec": ["exe", "args"],
    "echo": ["message"],
    "sleep": ["duration_in_seconds"],
    "frames-to-video": ["exe", "exeArgs", "fps", "inputGlob", "outputFile", "argsBefore", "args"],
    "move-directory": ["src", "dest"],
    "copy-file": ["src", "dest"],
};
// Parameters the worker refuses when missing or empty (cmdBlenderRenderParams: exe and blendfile).
const REQUIRED = { "blender-render": ["exe", "blendfile"], "exec": ["exe"] };
const SETTING_TYPES = ["string", "int32", "float", "bool", "hashed_file_path"];

function strict(name, obj) {
    return new Proxy(obj, {
        get(target, prop) {
            if (typeof prop === "symbol" || prop in target) {
                return target[prop];
            }
            throw new Error(`${name}.${String(prop)} is not part of Flamenco's job compiler API`);
        },
    });
}

function checkSettings(jobType, given) {
    const defs = {};
    for (const s of jobType.settings) {
        if (!SETTING_TYPES.includes(s.type)) {
            throw new Error(`setting ${s.key}: unknown type ${s.type}`);
        }
        defs[s.key] = s;
    }
    for (const key of Object.keys(given)) {
        if (!(key in defs)) {
            throw new Error(`setting ${key} is not in JOB_TYPE`);
        }
    }
    const out = {};
    for (const s of jobType.settings) {
        let value = key_in(given, s.key) ? given[s.key] : s.default;
        if (value === undefined && s.required) {
            throw new Error(`setting ${s.key} is required`);
        }
        if (value !== undefined && s.choices && !s.choices.includes(value)) {
            throw new Error(`setting ${s.key}: ${JSON.stringify(value)} is not one of ${s.choices.join(", ")}`);
        }
        if (value !== undefined) {
            out[s.key] = value;
        }
    }
    return out;
}

function key_in(obj, key) {
    return Object.prototype.hasOwnProperty.call(obj, key);
}

function main(argv) {
    const [scriptPath, settingsPath, metadataPath] = argv;
    const source = fs.readFileSync(scriptPath, "utf8");
    const tasks = [];
    const author = strict("author", {
        Task(name, type) {
            if (typeof name !== "string" || typeof type !== "string") {
                throw new Error("author.Task(name, type) takes two strings");
            }
            const task = { name, type, commands: [], dependencies: [] };
            return strict("task", {
                _record: task,
                addCommand(cmd) {
                    task.commands.push(cmd);
                },
                addDependency(other) {
                    task.dependencies.push(other._record.name);
                },
            });
        },
        Command(type, parameters, totalFrames) {
            if (!(type in WORKER_COMMANDS)) {
                throw new Error(`author.Command: Flamenco's worker has no command ${JSON.stringify(type)}`);
            }
            for (const key of Object.keys(parameters)) {
                if (!WORKER_COMMANDS[type].includes(key)) {
                    throw new Error(`author.Command(${type}): unknown parameter ${key}`);
                }
            }
            for (const key of REQUIRED[type] || []) {
                if (!parameters[key]) {
                    throw new Error(`author.Command(${type}): the worker refuses an empty '${key}'`);
                }
            }
            const cmd = { type, parameters: JSON.parse(JSON.stringify(parameters)) };
            if (totalFrames !== undefined) {
                cmd.totalFrames = totalFrames;
            }
            return cmd;
        },
    });
    const path = strict("path", {
        join: (...parts) => nodePath.posix.join(...parts),
        dirname: (p) => nodePath.posix.dirname(p),
        basename: (p) => nodePath.posix.basename(p),
        stem: (p) => nodePath.posix.parse(p).name,
    });
    const logs = [];
    const sandbox = { author, path, print: (...args) => logs.push(args.join(" ")) };
    vm.createContext(sandbox);
    const { JOB_TYPE, compileJob } = vm.runInContext(`${source}\n;({ JOB_TYPE, compileJob });`, sandbox, {
        filename: scriptPath,
    });
    if (!JOB_TYPE || typeof JOB_TYPE.label !== "string" || !Array.isArray(JOB_TYPE.settings)) {
        throw new Error("JOB_TYPE must have a label and a settings list");
    }
    if (typeof compileJob !== "function") {
        throw new Error("compileJob(job) is missing");
    }
    const settings = checkSettings(JOB_TYPE, JSON.parse(fs.readFileSync(settingsPath, "utf8")));
    const metadata = metadataPath ? JSON.parse(fs.readFileSync(metadataPath, "utf8")) : {};
    const job = strict("job", {
        settings,
        metadata,
        addTask(task) {
            tasks.push(task._record);
        },
    });
    compileJob(job);
    const names = new Set(tasks.map((t) => t.name));
    for (const t of tasks) {
        for (const dep of t.dependencies) {
            if (!names.has(dep)) {
                throw new Error(`task ${t.name} depends on ${dep}, which was never added to the job`);
            }
        }
    }
    process.stdout.write(JSON.stringify({ job_type: JOB_TYPE.label, settings, tasks, log: logs }, null, 2) + "\n");
}

try {
    main(process.argv.slice(2));
} catch (err) {
    process.stderr.write(`flamenco_harness: error: ${err instanceof Error ? err.message : String(err)}\n`);
    process.exit(1);
}
