"""Stop signals in every phase of ``cognet-jax train`` (the search itself: tests/test_checkpoint.py
and tests/test_sweep.py): while it compiles, and while it evaluates its best policy after the
search. The process ends within 10 s with one line and status 128 + the signal, never a
segmentation fault; what a finished search found is kept, and ``--resume`` completes it to the
uninterrupted run's numbers."""

import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from cognet_jax.checkpoint import CHECKPOINT_NAME
from cognet_jax.driver import train
from cognet_jax.registry import load_config
from cognet_jax.saved_runs import resume_target

ROOT = Path(__file__).resolve().parents[1]
TINY = [
    "algorithm.iterations=50",
    "algorithm.rollouts=40",
    "algorithm.top=8",
    "algorithm.keep=3",
    "algorithm.eval_rollouts=8",
    "network.train_steps=2",
    "run.plots=false",
]


def _start(out: Path, sets: list[str], cache: bool = False):
    """``cognet-jax train`` in a fresh process, its stderr lines in a queue; without ``cache``
    it has no compilation cache (it really compiles), with it the test session's."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu")
    args = [sys.executable, "-m", "cognet_jax", "train", "tagging-thesis-spec-n3", "--seed", "3"]
    args += ["--out", str(out), "--no-progress"]
    if not cache:
        env.pop("JAX_COMPILATION_CACHE_DIR", None)
        args.append("--no-compile-cache")
    args += [x for s in sets for x in ("--set", s)]
    proc = subprocess.Popen(
        args, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stderr], daemon=True).start()
    return proc, lines


def _wait_line(lines: queue.Queue, text: str, timeout: float = 120.0) -> list[str]:
    seen, t0 = [], time.time()
    while time.time() - t0 < timeout:
        try:
            seen.append(lines.get(timeout=0.05))
        except queue.Empty:
            continue
        if text in seen[-1]:
            return seen
    raise AssertionError(f"no line with {text!r}: {seen}")


def _stopped(proc, lines: queue.Queue, sig) -> list[str]:
    """Send ``sig``; the process must end within 10 s. Returns its remaining stderr lines."""
    t0 = time.time()
    proc.send_signal(sig)
    proc.wait(timeout=10)
    assert time.time() - t0 < 10
    time.sleep(0.2)
    rest = []
    while not lines.empty():
        rest.append(lines.get())
    assert proc.returncode == 128 + sig, rest
    text = "".join(rest)
    assert "Segmentation" not in text and "Traceback" not in text, text
    return [x.strip() for x in rest if x.strip()]


def test_sigterm_while_compiling_ends_at_once_and_leaves_no_folder(tmp_path):
    out = tmp_path / "run"
    proc, lines = _start(out, TINY)
    _wait_line(lines, "compiling")
    rest = _stopped(proc, lines, signal.SIGTERM)
    assert rest[-1].startswith("error:") and "SIGTERM" in rest[-1], rest
    if not (out / CHECKPOINT_NAME).exists():  # the signal came before an iteration finished
        assert rest[-1] == "error: stopped by SIGTERM" and not out.exists(), rest


@pytest.mark.optimised
def test_sigint_during_the_final_evaluation_keeps_the_search_then_resume_finishes_it(tmp_path):
    """The search has finished (its checkpoint is written) and the honest evaluation of 4
    million rollouts runs (about 1.1 s on the 2-core CPU; the signal comes 0.3 s after the
    checkpoint, and a loaded machine only makes the evaluation longer): Ctrl-C keeps the
    search's best policy and checkpoint; ``--resume`` skips the search and gives the
    uninterrupted run's value. The uninterrupted run comes first, in this process; the
    interrupted one loads its programs from the session's cache (the signal finds it
    evaluating, not compiling)."""
    sets = TINY + ["evaluation.rollouts=4000000", "run.checkpoint_seconds=0"]
    reference = train(load_config("tagging-thesis-spec-n3", sets), 3, tmp_path / "ref")
    assert reference["eval_s"] > 0.6  # (the window the signal below needs)
    out = tmp_path / "run"
    proc, lines = _start(out, sets, cache=True)
    ckpt = out / CHECKPOINT_NAME
    t0 = time.time()
    while not ckpt.exists():
        assert proc.poll() is None and time.time() - t0 < 120
        time.sleep(0.01)
    time.sleep(0.3)  # into the evaluation
    rest = _stopped(proc, lines, signal.SIGINT)
    assert "interrupted at iteration 50/50" in rest[-1] and "--resume" in rest[-1], rest
    partial = json.loads((out / "results.json").read_text())
    assert partial["status"] == "interrupted" and (out / "policy.msgpack").exists()
    config, seed = resume_target(out)
    resumed = train(config, seed, out, resume=True, log=lambda *_: None)
    assert resumed["resumed_from_iteration"] == 50
    assert resumed["final_value"] == reference["final_value"]
    assert resumed["values_per_iteration"] == reference["values_per_iteration"]


def test_a_signal_sent_twice_at_once_is_one_stop(tmp_path):
    """``timeout`` signals the command and then its process group, so the command gets
    SIGTERM twice at once: that is one stop, which keeps the search's best policy and its
    checkpoint (a second stop would cut the writing short)."""
    out = tmp_path / "run"
    proc, lines = _start(out, TINY + ["algorithm.iterations=100000"])
    _wait_line(lines, "compiled")
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    rest = _stopped(proc, lines, signal.SIGTERM)
    assert "interrupted at iteration" in rest[-1] and "--resume" in rest[-1], rest
    assert (out / "policy.msgpack").exists() and (out / CHECKPOINT_NAME).exists()


def test_sigterm_during_a_long_evaluate_ends_it_within_ten_seconds(tmp_path):
    """``cognet-jax evaluate`` of many rollouts says so first and obeys SIGTERM at once (the
    evaluation runs in a worker thread the command does not wait for)."""
    out = tmp_path / "run"
    small = ["algorithm.iterations=2", "evaluation.rollouts=100"]
    train(load_config("tagging-thesis-spec-n3", [*TINY, *small]), 0, out, progress=False)
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu")
    args = [sys.executable, "-m", "cognet_jax", "evaluate", str(out), "--rollouts", "100000000"]
    args += ["--set", "env.horizon=60"]  # about 1e10 agent-steps: minutes of work
    proc = subprocess.Popen(
        args, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stderr], daemon=True).start()
    _wait_line(lines, "100000000 rollouts")
    time.sleep(3.0)  # into the compiled evaluation
    rest = _stopped(proc, lines, signal.SIGTERM)
    assert rest and rest[-1].startswith("error: stopped by"), rest


def test_a_stop_signal_after_the_work_ends_the_process_with_one_line():
    """Once a command is done (``cli.run`` calls ``exit_on_stop``), a late SIGTERM ends the
    process with 143 and one line saying the output is complete: before, it could land in a
    callback of JAX's garbage collector and print a traceback of an ignored exception, status
    0."""
    import subprocess
    import sys

    code = (
        "import os, signal, sys, time\n"
        "from cognet_jax.signals import exit_on_stop, install_stop_handlers\n"
        "install_stop_handlers()\n"
        "print('done', flush=True)\n"
        "exit_on_stop()\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "time.sleep(10)\n"
        "sys.exit(5)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout) == (143, "done\n")
    assert done.stderr.splitlines() == [
        "error: stopped by SIGTERM after the command finished (its output is complete)"
    ]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_while_the_command_starts_is_one_line(tmp_path, sig):
    """A signal in the first second, while the command line still imports JAX: one line and
    status 128 + the signal (no traceback of the import, no silent exit), nothing written."""
    proc, lines = _start(tmp_path / "run", TINY)
    time.sleep(0.4)
    rest = _stopped(proc, lines, sig)
    assert len(rest) == 1 and rest[0].startswith(f"error: stopped by {sig.name}"), rest
    assert not (tmp_path / "run").exists()


def test_a_stop_raised_inside_a_compiled_call_is_reported_as_the_stop(monkeypatch, capsys):
    """JAX wraps an exception raised while it dispatches a computation (the stop handler's
    ``Stopped``) in its own error, "Error dispatching computation": the command still ends
    as stopped by the signal, not with an internal error."""
    from cognet_jax import cli
    from cognet_jax.signals import Stopped, install_stop_handlers

    def dispatching(args):
        try:
            os.kill(os.getpid(), signal.SIGTERM)  # the handler raises Stopped here
            time.sleep(5)
        except Stopped:  # as JAX's dispatch hands it on
            raise RuntimeError("INTERNAL: Error dispatching computation") from None

    monkeypatch.setattr(cli, "_evaluate", dispatching)
    previous = signal.getsignal(signal.SIGTERM)
    install_stop_handlers()
    try:
        code = cli.main(["evaluate", "somewhere"])
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert code == 128 + signal.SIGTERM
    assert capsys.readouterr().err.strip() == "error: stopped by SIGTERM"


def test_long_iterations_are_dispatched_one_at_a_time():
    """Iterations over ``ONE_AHEAD_S`` stay one deep, so a stop waits for one iteration, not
    for a second one queued behind it; short ones queue about ``AHEAD_S`` of them."""
    import time as clock

    import jax.numpy as jnp

    from cognet_jax import loop

    ahead = loop.Ahead({"x": jnp.zeros(3)})
    assert ahead.depth == 1  # the first iteration alone, until its time is known
    ahead.t0 = clock.perf_counter() - 2 * loop.ONE_AHEAD_S
    ahead.finished()
    assert ahead.depth == 1
    ahead = loop.Ahead({"x": jnp.zeros(3)})
    ahead.t0 = clock.perf_counter() - loop.AHEAD_S / 10
    ahead.finished()
    assert ahead.depth >= 2
