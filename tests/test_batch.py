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


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A real local Ray cluster: `ray start --head` bound to 127.0.0.1 with two CPUs, stopped at the end."""
    import os
    import shutil
    import socket
    import subprocess
    import sys

    ray = shutil.which("ray", path=os.path.dirname(sys.executable)) or "ray"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_TMPDIR": str(tmp_path_factory.mktemp("ray"))}
    subprocess.run([ray, "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}", "--num-cpus=2",
                    "--include-dashboard=false", "--disable-usage-stats"], check=True, env=env, capture_output=True,
                   timeout=180)
    try:
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([ray, "stop", "--force"], env=env, capture_output=True, timeout=120)


def test_the_same_batch_on_a_ray_cluster_gives_the_same_report(inputs, tmp_path, ray_cluster):
    local, remote = tmp_path / "local", tmp_path / "ray"
    (inputs / "broken.safetensors").write_bytes(b"not a checkpoint")  # as the first test found it
    assert main(["batch", str(inputs / "jobs.yaml"), "--out", str(local), "--workers", "2", "--quiet"]) == 1
    assert main(["batch", str(inputs / "jobs.yaml"), "--out", str(remote), "--ray", ray_cluster, "--quiet"]) == 1
    a = json.loads((local / "report.json").read_text())["jobs"]
    b = json.loads((remote / "report.json").read_text())["jobs"]
    assert {n: e["status"] for n, e in a.items()} == {n: e["status"] for n, e in b.items()}
    assert a["broken"]["error"] == b["broken"]["error"]
    assert sorted(p.relative_to(local).as_posix() for p in local.rglob("*") if p.is_file()) == \
        sorted(p.relative_to(remote).as_posix() for p in remote.rglob("*") if p.is_file())
