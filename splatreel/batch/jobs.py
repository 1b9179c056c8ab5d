"""Jobs files of ``splatreel batch``: what to do with each input, as the commands it becomes.

YAML::

    defaults:                      # options every job's steps take unless the job says otherwise
      train: {minutes: 2}
      render: {size: 640x360}
    jobs:
      - name: spinner              # the job's folder under --out (default: the input's file or folder name)
        input: data/spinner        # a dataset (for train, eval) or a model file (anything `info` reads)
        steps: [train, eval, render, export usd]
        train: {minutes: 1}        # this job's options for a step (`--minutes 1`)
      - input: models/walker.pth
        steps: [convert, export gltf]

CSV (one job a row): columns ``name``, ``input``, ``steps`` (space-separated, ``export`` steps as ``export-usd``),
and any ``STEP.OPTION`` column (``train.minutes``, ``render.size``); an empty cell is no option.

Each step is one ``splatreel`` command on the job's model, writing into ``OUT/NAME/``: ``train`` (the input dataset
-> ``model.safetensors``), ``convert`` (the input file -> ``model.safetensors``), ``eval`` (``eval.json``, needs a
dataset input and a model), ``render`` (``render.mp4``), ``export FORMAT`` (``export-FORMAT`` plus the format's
usual suffix or folder). A job without ``train``/``convert`` uses its input as the model.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import SplatreelError

#: Export formats and the name of their output in a job's folder.
EXPORT_OUTPUTS = {"usd": "export.usdc", "mesh": "mesh", "ply": "ply", "gltf": "gltf", "splatv": "model.splatv",
                  "4dgs": "model.4dgs", "web": "web"}
STEPS = ("train", "convert", "eval", "render", *(f"export {f}" for f in EXPORT_OUTPUTS))
MODEL = "model.safetensors"


class JobsFileError(SplatreelError):
    """A jobs file that cannot be read or names unknown steps."""


@dataclass(frozen=True)
class Job:
    """One input and the steps to run on it (`options`: step -> option name -> value)."""

    name: str
    input: str
    steps: tuple[str, ...]
    options: dict = field(default_factory=dict)

    def model_path(self, folder: Path) -> str:
        """The model the steps after train/convert read: that output, else the input."""
        return str(folder / MODEL) if {"train", "convert"} & set(self.steps) else self.input


@dataclass(frozen=True)
class Command:
    """One step of a job as ``splatreel`` arguments, and the output it writes."""

    step: str
    argv: tuple[str, ...]
    output: Path


def option_args(options: dict) -> list[str]:
    """``{"minutes": 1, "no_densify": True, "crop": [0, 0, 0, 1, 1, 1]}`` -> command-line arguments."""
    argv = []
    for name, value in options.items():
        flag = "--" + str(name).replace("_", "-")
        if value is True:
            argv.append(flag)
        elif value is False or value is None or value == "":
            continue
        elif isinstance(value, (list, tuple)):
            argv += [flag, *map(str, value)]
        else:
            argv += [flag, str(value)]
    return argv


def commands(job: Job, folder: Path) -> list[Command]:
    """The ``splatreel`` invocations of `job`, writing into `folder`, in order."""
    model = job.model_path(folder)
    out = []
    for step in job.steps:
        extra = option_args(job.options.get(step, {}))
        if step in ("train", "convert"):
            target = folder / MODEL
            argv = [step, job.input, "--out", str(target), "--force", *extra]
        elif step == "eval":
            target = folder / "eval.json"
            argv = ["eval", model, job.input, "--out", str(target), "--force", *extra]
        elif step == "render":
            target = folder / "render.mp4"
            argv = ["render", model, "--out", str(target), "--force", "--quiet", *extra]
        else:
            fmt = step.split()[1]
            target = folder / f"export-{EXPORT_OUTPUTS[fmt]}"
            argv = ["export", fmt, model, "--out", str(target), "--force", "--quiet", *extra]
        if step == "train":
            argv.append("--quiet")
        out.append(Command(step, tuple(argv), target))
    return out


def _steps(value, where: str) -> tuple[str, ...]:
    items = value.split() if isinstance(value, str) else list(value or [])
    steps, i = [], 0
    while i < len(items):  # "export usd" in a YAML list, "export-usd" or "export usd" in a CSV cell
        item = str(items[i]).replace("-", " ", 1) if str(items[i]).startswith("export-") else str(items[i])
        if item == "export" and i + 1 < len(items):
            item, i = f"export {items[i + 1]}", i + 1
        if item not in STEPS:
            raise JobsFileError(f"{where}: unknown step {item!r}; steps are {', '.join(STEPS)}")
        steps.append(item)
        i += 1
    if not steps:
        raise JobsFileError(f"{where}: no steps")
    return tuple(steps)


def _job(entry: dict, defaults: dict, where: str, names: set) -> Job:
    if not isinstance(entry, dict) or not entry.get("input"):
        raise JobsFileError(f"{where}: a job needs an 'input'")
    steps = _steps(entry.get("steps"), where)
    name = str(entry.get("name") or Path(str(entry["input"]).rstrip("/")).stem)
    if name in names:
        raise JobsFileError(f"{where}: two jobs are named {name!r}; give each a 'name'")
    names.add(name)
    options = {}
    for step in steps:
        merged = {**defaults.get(step, {}), **(entry.get(step) or {})}
        if merged:
            options[step] = merged
    return Job(name, str(entry["input"]), steps, options)


def read_jobs(path: str | Path) -> list[Job]:
    """The jobs of a ``.yaml``/``.yml`` or ``.csv`` jobs file (see module doc); JobsFileError naming the problem."""
    path = Path(path)
    if not path.is_file():
        raise JobsFileError(f"{path}: no such jobs file")
    names: set = set()
    if path.suffix.lower() in (".yaml", ".yml"):
        import yaml

        try:
            doc = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise JobsFileError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
        if not isinstance(doc, dict) or not isinstance(doc.get("jobs"), list):
            raise JobsFileError(f"{path}: expected a mapping with a 'jobs' list")
        defaults = doc.get("defaults") or {}
        base = path.parent
        jobs = [_job(entry, defaults, f"{path}: job {i + 1}", names) for i, entry in enumerate(doc["jobs"])]
    elif path.suffix.lower() == ".csv":
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        base = path.parent
        jobs = []
        for i, row in enumerate(rows):
            entry = {"name": row.get("name"), "input": row.get("input"), "steps": row.get("steps", "")}
            for key, value in row.items():
                if key and "." in key and value not in (None, ""):
                    step, option = key.split(".", 1)
                    step = step.replace("-", " ", 1) if step.startswith("export-") else step
                    entry.setdefault(step, {})[option] = value
            jobs.append(_job(entry, {}, f"{path}: row {i + 2}", names))
    else:
        raise JobsFileError(f"{path}: a jobs file is .yaml, .yml or .csv")
    # relative inputs are relative to the jobs file, as a user writing it next to the data expects
    return [Job(j.name, j.input if Path(j.input).is_absolute() else str(base / j.input), j.steps, j.options)
            for j in jobs]
