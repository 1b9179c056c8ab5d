"""``splatreel batch``: a jobs file of tiny datasets and models run locally with 2 workers, one job corrupt."""

from __future__ import annotations

import csv
import json

import pytest

from splatreel.batch import JobsFileError, commands, read_jobs
from splatreel.cli import main


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    root = tmp_path_factory.mktemp("batch")
    assert main(["sample", "spinner", "--out", str(root / "data"), "--views", "2", "--time-steps", "2", "--size",
                 "32", "--test-views", "1", "--model", str(root / "spinner.safetensors"), "--gaussians", "300"]) == 0
    (root / "broken.safetensors").write_bytes(b"not a checkpoint")
    (root / "jobs.yaml").write_text("""
defaults:
  render: {size: 32x24, frame-count: 2}
jobs:
  - name: model
    input: spinner.safetensors
    steps: [export ply, render]
  - name: trained
    input: data
    steps: [train, eval]
    train: {iters: 3, num-gaussians: 200}
  - name: broken
    input: broken.safetensors
    steps: [export ply]
""")
    return root


def test_the_jobs_file_becomes_commands(inputs, tmp_path):
    jobs = read_jobs(inputs / "jobs.yaml")
    assert [j.name for j in jobs] == ["model", "trained", "broken"]
    model_cmds = commands(jobs[0], tmp_path / "model")
    assert [c.step for c in model_cmds] == ["export ply", "render"]
    assert model_cmds[1].argv[:2] == ("render", str(inputs / "spinner.safetensors"))
    assert "--size" in model_cmds[1].argv and "32x24" in model_cmds[1].argv  # the defaults
    train, evaluate = commands(jobs[1], tmp_path / "trained")
    assert train.argv[:2] == ("train", str(inputs / "data")) and ("--iters", "3") == train.argv[
        train.argv.index("--iters"):train.argv.index("--iters") + 2]
    assert evaluate.argv[1] == str(train.output)  # eval reads the model train wrote
    (tmp_path / "jobs.csv").write_text("name,input,steps,render.size\nm,spinner.safetensors,export-usd render,16x16\n")
    (job,) = read_jobs(tmp_path / "jobs.csv")
    assert job.steps == ("export usd", "render") and job.options == {"render": {"size": "16x16"}}
    (tmp_path / "bad.yaml").write_text("jobs:\n  - input: x\n    steps: [train, bake]\n")
    with pytest.raises(JobsFileError, match="unknown step 'bake'"):
        read_jobs(tmp_path / "bad.yaml")


def test_a_batch_runs_reports_the_corrupt_job_alone_and_skips_finished_jobs(inputs, tmp_path, capsys):
    out = tmp_path / "runs"
    args = ["batch", str(inputs / "jobs.yaml"), "--out", str(out), "--workers", "2", "--quiet"]
    assert main(args) == 1  # one job failed
    report = json.loads((out / "report.json").read_text())["jobs"]
    assert {n: e["status"] for n, e in report.items()} == {"model": "done", "trained": "done", "broken": "failed"}
    assert (out / "model" / "export-ply" / "manifest.json").exists() and (out / "model" / "render.mp4").exists()
    assert (out / "trained" / "model.safetensors").exists() and report["trained"]["metrics"]["psnr"] > 0
    error = report["broken"]["error"]
    assert "broken.safetensors" in error and "\n" not in error and error.startswith("splatreel export: error:")
    rows = list(csv.DictReader(open(out / "summary.csv")))
    assert [r["name"] for r in rows] == ["model", "trained", "broken"] and float(rows[1]["psnr"]) > 0
    assert "failed: broken:" in capsys.readouterr().out
    # again: the done jobs are skipped (their outputs untouched), the failed one only with --retry-failed
    stamp = (out / "model" / "render.mp4").stat().st_mtime_ns
    assert main(args) == 1
    assert (out / "model" / "render.mp4").stat().st_mtime_ns == stamp
    assert json.loads((out / "report.json").read_text())["jobs"]["trained"] == report["trained"]
    (inputs / "broken.safetensors").write_bytes((inputs / "spinner.safetensors").read_bytes())  # fixed
    assert main(args + ["--retry-failed"]) == 0
    assert json.loads((out / "report.json").read_text())["jobs"]["broken"]["status"] == "done"
    assert (out / "model" / "render.mp4").stat().st_mtime_ns == stamp
