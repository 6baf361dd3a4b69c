"""A training run killed with SIGKILL resumes with one override and loses at most its checkpoint interval;
a kill during a checkpoint save leaves the previous checkpoint whole; the killed run's results.json ends up
"interrupted"."""

from __future__ import annotations

import csv
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from gnsx.core import runstate
from gnsx.model.checkpoint import read_checkpoint
from gnsx.training.resilience import AtomicCheckpointIO, remove_stale_temporaries

ROOT = Path(__file__).resolve().parents[1]
TINY = ["model.latent_size=8", "model.mlp_hidden_size=8", "model.mp_steps=2"]


def _command(dataset: Path, run_dir: Path, *extra: str) -> list[str]:
    """A tiny training run whose only checkpoints are the wall-clock ones (every 1.2 s)."""
    return [
        sys.executable, str(ROOT / "train.py"), f"data.root={dataset}", "data.generate_if_missing=false",
        f"hydra.run.dir={run_dir}", "logger=csv", "threads=1", "evaluate.enabled=false", *TINY,
        "train.max_steps=150", "train.max_time=null", "train.log_every_n_steps=1",
        "train.val_every_n_steps=100000", "train.checkpoint_every_n_steps=100000",
        "train.permanent_every_n_steps=100000", "train.checkpoint_every_minutes=0.02", *extra,
    ]  # fmt: skip


def _logged_steps(run_dir: Path) -> list[int]:
    steps = []
    for path in (run_dir / "csv").glob("version_*/metrics.csv"):
        with open(path) as f:
            steps += [int(row["step"]) for row in csv.DictReader(f) if row.get("train/loss")]
    return sorted(steps)


@pytest.mark.slow  # end-to-end (~10-25 s): `make test-slow`; keeps `make test` under 5 min
def test_sigkill_then_resume_with_one_override(tmp_path, tiny_dataset):
    start = time.monotonic()
    first, second = tmp_path / "first", tmp_path / "second"
    last = first / "checkpoints" / "last.ckpt"
    log = open(tmp_path / "first.log", "w")
    job = subprocess.Popen(_command(tiny_dataset, first), cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT)
    try:
        while not last.exists():  # the first wall-clock checkpoint
            assert job.poll() is None, (tmp_path / "first.log").read_text()[-3000:]
            assert time.monotonic() - start < 120, "no checkpoint within 2 minutes"
            time.sleep(0.05)
        time.sleep(0.5)  # anywhere in the next interval, a save possibly in flight
        running = json.loads((first / "results.json").read_text())
        job.send_signal(signal.SIGKILL)
        job.wait(timeout=30)
    finally:
        if job.poll() is None:
            job.kill()
        log.close()
    killed_at = time.monotonic() - start
    assert running["status"] == "running" and running["pid"] == job.pid
    step_saved = int(read_checkpoint(last)["global_step"])  # whole and readable after the kill
    steps_before = _logged_steps(first)
    assert 0 < step_saved < 150 and max(steps_before) < 150  # killed mid-run

    resume = subprocess.run(_command(tiny_dataset, second, f"train.ckpt_path={first}"), cwd=tmp_path,
                            capture_output=True, text=True, timeout=300)  # fmt: skip
    assert resume.returncode == 0, resume.stdout[-2000:] + resume.stderr[-3000:]
    resumed_steps = _logged_steps(second)
    # Continued from the checkpoint (not from 0), and lost only the steps after it.
    assert min(resumed_steps) >= step_saved and max(resumed_steps) < 150
    assert int(read_checkpoint(second / "checkpoints" / "last.ckpt")["global_step"]) == 150
    killed = json.loads((first / "results.json").read_text())
    assert killed["status"] == "interrupted" and killed["resumed_in"] == str(second)
    assert f"train.ckpt_path={first}" in killed["error"]
    assert json.loads((second / "results.json").read_text())["status"] == "ok"
    total = time.monotonic() - start
    print(
        f"\nkilled after {killed_at:.1f} s at logged step {max(steps_before)}, checkpoint at step "
        f"{step_saved}, resumed from {min(resumed_steps)} to 150; test {total:.1f} s"
    )


def _save_then_die(path: str) -> None:
    """In a child process: start writing a checkpoint, then SIGKILL itself halfway through the write."""

    def half_then_kill(obj, f, *args, **kwargs):
        f.write(b"PK\x03\x04" + b"\0" * 4096)
        f.flush()
        os.kill(os.getpid(), signal.SIGKILL)

    torch.save = half_then_kill
    AtomicCheckpointIO().save_checkpoint({"state_dict": {}, "global_step": 2}, path)


def test_a_kill_during_a_save_leaves_the_previous_checkpoint_whole(tmp_path):
    last = tmp_path / "last.ckpt"
    io = AtomicCheckpointIO()
    state = {"state_dict": {"w": torch.ones(3)}, "hyper_parameters": {"model": {}}, "global_step": 1}
    io.save_checkpoint(state, last)
    before = last.read_bytes()
    child = multiprocessing.get_context("fork").Process(target=_save_then_die, args=(str(last),))
    child.start()
    child.join(timeout=60)
    assert child.exitcode == -signal.SIGKILL
    assert last.read_bytes() == before  # untouched
    assert read_checkpoint(last)["global_step"] == 1
    assert torch.equal(io.load_checkpoint(last)["state_dict"]["w"], torch.ones(3))
    stale = remove_stale_temporaries(tmp_path)
    assert len(stale) == 1 and stale[0].name.startswith(".last.ckpt.") and not stale[0].exists()


def test_a_dead_running_record_reads_as_interrupted(tmp_path):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    record = {"status": "running", "run_dir": str(tmp_path), "global_step": 7, **runstate.liveness()}
    assert runstate.effective_status(record) == "running"  # this very process
    record["pid"], record["pid_start"] = dead.pid, None
    assert runstate.effective_status(record) == "interrupted"
    elsewhere = {**record, "host": "another-host"}
    assert runstate.effective_status(elsewhere) == "running"  # fresh heartbeat: cannot tell yet
    stale = {**elsewhere, "heartbeat": time.time() - runstate.STALE_S - 1}
    assert runstate.effective_status(stale) == "interrupted"
    assert runstate.effective_status({"status": "running"}) == "running"  # old record: nothing tells
    assert runstate.effective_status({**record, "status": "ok"}) == "ok"
    path = tmp_path / "results.json"
    path.write_text(json.dumps(record))
    marked = runstate.mark_interrupted(path, resumed_in="elsewhere")
    assert marked["status"] == "interrupted" and "at step 7" in marked["error"]
    assert json.loads(path.read_text())["resumed_in"] == "elsewhere"
    assert runstate.mark_interrupted(path) is None  # already marked: left alone


@pytest.mark.parametrize("pid_start_offset", [1])
def test_a_reused_pid_is_not_the_job(pid_start_offset):
    me = runstate.liveness()
    assert runstate.pid_alive(me["pid"], me["pid_start"])
    if me["pid_start"] is not None:
        assert not runstate.pid_alive(me["pid"], me["pid_start"] + pid_start_offset)
