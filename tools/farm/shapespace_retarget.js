// SPDX-License-Identifier: GPL-3.0-or-later
//
// ShapeSpace batch retarget as a Flamenco job type (Blender Studio's render farm manager).
//
// Install: copy this file into the Manager's `scripts/` folder (next to flamenco-manager) and restart it;
// the job type "ShapeSpace Retarget" then shows in the Flamenco add-on's job types.  Submit it from Blender
// with the rig file open: `blendfile` (set by the add-on) is the rig.
//
// Tasks: one per take (or per chunk of `chunk_size` takes), each running, for every take of its chunk,
//     {blender} {blenderArgs} RIG --command shapespace retarget --source TAKE [--object OBJ] [BONES] --method M
//         --key-tolerance T --out OUTPUT_DIR/<take>.blend --report OUTPUT_DIR/<take>.json
// — the batch command with one --source — then a merge task (depends on all of them):
//     {blender} {blenderArgs} RIG --command shapespace merge-reports --takes TAKE… --reports-dir OUTPUT_DIR
//         --out OUTPUT_DIR/merged.json
// `{blender}` and `{blenderArgs}` are the Manager's two-way variables (as in Flamenco's own job types).
//
// ShapeSpace on the worker: with `extension_zip` set, every task first installs it with Blender's own
// command, `{blender} -b RIG --command extension install-file -r user_default -e ZIP` (idempotent, same worker as
// the take); leave it empty when the workers share an extensions repository where ShapeSpace is installed.

const JOB_TYPE = {
    label: "ShapeSpace Retarget",
    description: "Retarget Live Link Face takes onto the shape-key rig of this file, one task per take, then " +
        "merge the per-take reports",
    settings: [
        { key: "takes", type: "string", required: true, visible: "submission",
          description: "Takes to retarget: capture recordings (Live Link Face CSV, Face Cap TXT, iFacialMocap, " +
              "Audio2Face or MediaPipe JSON/CSV) or action names, separated by ';', or a JSON list of paths " +
              "(for a path that holds ';')" },
        { key: "chunk_size", type: "int32", default: 1, propargs: { min: 1 }, visible: "submission",
          description: "Takes per task" },
        { key: "output_dir", type: "string", subtype: "dir_path", required: true, visible: "submission",
          description: "Where each take's .blend and .json and the merged report go" },
        { key: "method", type: "string", default: "spacetime", visible: "submission",
          choices: ["copy", "learned", "perframe", "spacetime"], description: "Retarget method" },
        { key: "key_tolerance", type: "float", default: 0.0, propargs: { min: 0.0 }, visible: "submission",
          description: "Reduce keys to this max slider error (0 keeps every frame)" },
        { key: "target_object", type: "string", default: "", visible: "submission",
          description: "Target mesh when the rig file has several meshes with shape keys" },
        { key: "head_bone", type: "string", default: "", visible: "submission",
          description: "Bone keyed from the head rotation (empty, with neck and eye bones empty too: the bones " +
              "stored on the rig, if any)" },
        { key: "neck_bone", type: "string", default: "", visible: "submission",
          description: "Bone taking 'neck share' of the head rotation (empty: none)" },
        { key: "neck_share", type: "float", default: 0.3, propargs: { min: 0.0, max: 1.0 }, visible: "submission",
          description: "The neck bone's share of the head rotation" },
        { key: "left_eye_bone", type: "string", default: "", visible: "submission",
          description: "The character's left eye bone (empty: none)" },
        { key: "right_eye_bone", type: "string", default: "", visible: "submission",
          description: "The character's right eye bone (empty: none)" },
        { key: "armature", type: "string", default: "", visible: "submission",
          description: "The armature of those bones (empty: the only armature in the rig file)" },
        { key: "extension_zip", type: "string", subtype: "file_path", default: "", visible: "submission",
          description: "ShapeSpace zip to install on the worker first (empty: already installed there)" },
        { key: "blendfile", type: "string", required: true, visible: "web",
          description: "The rig: the .blend the job was submitted from" },
    ],
};

function compileJob(job) {
    print("ShapeSpace Retarget job submitted");
    const settings = job.settings;
    const takes = splitTakes(settings.takes);
    if (takes.length === 0) {
        throw "no takes given: list the take files in 'takes', separated by ';'";
    }
    const stems = takes.map(takeStem);
    const seen = {};
    stems.forEach((stem, i) => {
        if (seen[stem] !== undefined) {
            throw `takes ${takes[seen[stem]]} and ${takes[i]} would both write ${stem}.json: rename one`;
        }
        seen[stem] = i;
    });
    const chunkSize = Math.max(1, settings.chunk_size || 1);
    const retargetTasks = [];
    for (let start = 0; start < takes.length; start += chunkSize) {
        const chunk = takes.slice(start, start + chunkSize);
        const task = author.Task(`retarget-${chunk.map(takeStem).join("+")}`, "blender");
        if (settings.extension_zip) {
            task.addCommand(blenderCommand(settings.blendfile, installArgs(settings.extension_zip)));
        }
        for (const take of chunk) {
            task.addCommand(blenderCommand(settings.blendfile, retargetArgs(settings, take)));
        }
        job.addTask(task);
        retargetTasks.push(task);
    }
    const merge = author.Task("merge-reports", "blender");
    if (settings.extension_zip) {
        merge.addCommand(blenderCommand(settings.blendfile, installArgs(settings.extension_zip)));
    }
    merge.addCommand(blenderCommand(settings.blendfile, ["--command", "shapespace", "merge-reports", "--takes"].concat(takes, [
        "--reports-dir", settings.output_dir, "--out", path.join(settings.output_dir, "merged.json")])));
    for (const task of retargetTasks) {
        merge.addDependency(task);
    }
    job.addTask(merge);
}

// The takes: a JSON list of paths (exact: a path may hold ';'), else paths separated by ';'.  A take shaped
// like a flag (a leading '-') is refused: `--takes` would read it as an option of merge-reports.
function splitTakes(text) {
    const given = (text || "").trim();
    let takes;
    if (given.startsWith("[")) {
        let list;
        try {
            list = JSON.parse(given);
        } catch (err) {
            throw `takes: not a JSON list of paths (${err.message}); or separate the paths with ';'`;
        }
        if (!Array.isArray(list) || !list.every((t) => typeof t === "string")) {
            throw "takes: the JSON list must hold only paths (strings)";
        }
        takes = list;
    } else {
        takes = given.split(";");
        // "/takes/a;b.csv" split in two leaves a folder path without a file extension: refuse it, never run it
        const cut = takes.map((t) => t.trim()).find((t) => /[\\/]/.test(t) && !/\.[^.\\/]+$/.test(t));
        if (takes.length > 1 && cut !== undefined) {
            throw `takes: ${JSON.stringify(cut)} is a path without a file name extension: is it part of a path ` +
                "holding ';'? Give the takes as a JSON list of paths";
        }
    }
    takes = takes.map((t) => t.trim()).filter((t) => t.length > 0);
    for (const take of takes) {
        if (take.startsWith("-")) {
            throw `take ${JSON.stringify(take)} looks like a command-line flag: give it as a path (./${take})`;
        }
    }
    return takes;
}

function takeStem(take) {
    return path.basename(take).replace(/\.[^.]*$/, "");
}

function installArgs(zip) {
    return ["--command", "extension", "install-file", "-r", "user_default", "-e", zip];
}

function retargetArgs(settings, take) {
    const stem = takeStem(take);
    let args = ["--command", "shapespace", "retarget", "--source", take];
    if (settings.target_object) {
        args = args.concat(["--object", settings.target_object]);
    }
    return args.concat(boneArgs(settings), [
        "--method", settings.method,
        "--key-tolerance", String(settings.key_tolerance),
        "--out", path.join(settings.output_dir, `${stem}.blend`),
        "--report", path.join(settings.output_dir, `${stem}.json`),
    ]);
}

// `--head-bone/--neck-bone/--eye-bones/--neck-share/--armature` when a bone is named (none: the CLI keys the bones
// stored on the rig, if any).  A name shaped like a flag is refused.
function boneArgs(settings) {
    const names = ["head_bone", "neck_bone", "left_eye_bone", "right_eye_bone", "armature"];
    for (const key of names) {
        if ((settings[key] || "").startsWith("-")) {
            throw `${key} ${JSON.stringify(settings[key])} looks like a command-line flag`;
        }
    }
    let args = [];
    if (settings.head_bone) {
        args = args.concat(["--head-bone", settings.head_bone]);
    }
    if (settings.neck_bone) {
        args = args.concat(["--neck-bone", settings.neck_bone]);
    }
    if (settings.left_eye_bone || settings.right_eye_bone) {
        args = args.concat(["--eye-bones", settings.left_eye_bone || "", settings.right_eye_bone || ""]);
    }
    if (args.length === 0) {
        return args;
    }
    const share = settings.neck_share === undefined ? 0.3 : settings.neck_share;
    args = args.concat(["--neck-share", String(share)]);
    return settings.armature ? args.concat(["--armature", settings.armature]) : args;
}

// Flamenco's Blender command: {blender} {blenderArgs} [argsBefore…] blendfile [args…].  The worker requires a
// blend file, so the install and merge commands open the rig too (harmless: they do not touch it).
function blenderCommand(blendfile, args) {
    return author.Command("blender-render", {
        exe: "{blender}",
        exeArgs: "{blenderArgs}",
        argsBefore: [],
        blendfile: blendfile,
        args: args,
    });
}
