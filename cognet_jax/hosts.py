"""Several processes, devices and hosts for a sweep: ``jax.distributed`` started from
``--coordinator`` / ``--cluster`` (the coordinator checked first), and the CPU split into JAX
devices."""

from __future__ import annotations

import os
import subprocess
import sys
import time

from cognet_jax.config import ConfigError
from cognet_jax.errors import UsageError
from cognet_jax.signals import in_background


def init_distributed(args) -> None:
    """``jax.distributed.initialize`` from ``--coordinator/--num-processes/--process-id`` or,
    with ``--cluster``, from the cluster scheduler's environment variables."""
    import jax

    explicit = (args.coordinator, args.num_processes, args.process_id)
    if args.cluster:
        try:  # in a worker thread, as below: a stop signal ends the wait for the peers
            in_background(jax.distributed.initialize)
        except (RuntimeError, ValueError) as err:
            raise UsageError(f"--cluster: cannot start jax.distributed: {err}") from None
    elif any(v is not None for v in explicit):
        for name, v in zip(("--coordinator", "--num-processes", "--process-id"), explicit):
            if v is None:
                raise UsageError(f"{name} is needed for a multi-process sweep")
        if args.num_processes < 1:
            raise UsageError(f"--num-processes must be >= 1, got {args.num_processes}")
        if not 0 <= args.process_id < args.num_processes:
            raise UsageError(f"--process-id must be in 0 .. {args.num_processes - 1}")
        check_coordinator(args.coordinator, args.process_id)
        try:  # in a worker thread: a stop signal ends the wait at once (it held the signal
            # until JAX's own timeout aborted the process)
            in_background(
                lambda: jax.distributed.initialize(
                    args.coordinator,
                    args.num_processes,
                    args.process_id,
                    initialization_timeout=COORDINATOR_TIMEOUT_S,
                )
            )
        except (RuntimeError, ValueError) as err:
            raise UsageError(f"--coordinator {args.coordinator}: cannot start: {err}") from None


#: how long the processes of a multi-process sweep wait for each other
COORDINATOR_TIMEOUT_S = 120


def check_coordinator(address: str, process_id: int) -> None:
    """Refuse, in one line, what would make ``jax.distributed`` abort the process natively: an
    address that is not ``HOST:PORT``, a host that does not resolve, a port process 0 cannot
    listen on, and (other processes) a coordinator that does not answer within
    ``COORDINATOR_TIMEOUT_S``. (A peer process that never starts still ends JAX's own wait
    with an abort, after that timeout.)"""
    import socket

    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise UsageError(f"--coordinator {address!r}: expected HOST:PORT (a port 1-65535)")
    try:
        socket.getaddrinfo(host.strip("[]"), int(port), type=socket.SOCK_STREAM)
    except OSError as err:
        raise UsageError(f"--coordinator {address}: unknown host {host!r} ({err})") from None
    if process_id == 0:  # the coordination service runs here and listens on PORT
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                probe.bind(("", int(port)))
        except OSError as err:
            raise UsageError(
                f"--coordinator {address}: process 0 cannot listen on port {port} ({err.strerror})"
            ) from None
        return
    deadline, told = time.monotonic() + COORDINATOR_TIMEOUT_S, False
    while True:
        try:
            socket.create_connection((host.strip("[]"), int(port)), timeout=2).close()
            return
        except OSError:
            if time.monotonic() > deadline:
                raise UsageError(
                    f"--coordinator {address}: no answer in {COORDINATOR_TIMEOUT_S} s (start "
                    "process 0 first, on that host)"
                ) from None
            if not told:
                print(f"waiting for the coordinator at {address} ...", file=sys.stderr)
                told = True
            time.sleep(0.5)


def set_cpu_devices(requested: int | None, runs: int) -> None:
    """Split the host CPU into ``requested`` JAX devices (default ``min(cores, runs)``) so the
    sharded ``[runs]`` axis keeps every core busy. Must run before JAX starts its backends;
    does nothing when ``XLA_FLAGS`` already sets the host device count."""
    import jax

    if requested is not None and requested < 1:
        raise ConfigError("cpu-devices", f"must be >= 1, got {requested}")
    if "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", ""):
        return
    n = requested if requested is not None else max(1, min(os.cpu_count() or 1, runs))
    try:
        jax.config.update("jax_num_cpu_devices", n)
    except RuntimeError:  # backends already started (e.g. called from a running program)
        pass


#: the environment variables of JAX's transfer guards
TRANSFER_GUARDS = tuple(
    "JAX_TRANSFER_GUARD" + side
    for side in ("", "_HOST_TO_DEVICE", "_DEVICE_TO_HOST", "_DEVICE_TO_DEVICE")
)


def check_jax_settings() -> None:
    """``UsageError`` for a JAX setting the package's programs cannot run under, read from
    JAX's configuration (the environment's ``JAX_*`` variables) without starting a backend:
    programs are compiled ahead of time (no ``JAX_DISABLE_JIT``) and broadcast ranks
    implicitly (``JAX_NUMPY_RANK_PROMOTION`` "allow" or "warn") and moves values between host
    and device (no transfer guard "disallow")."""
    import jax

    if jax.config.jax_disable_jit:
        raise UsageError(
            "JAX_DISABLE_JIT is set: cognet-jax compiles its programs ahead of time; unset it"
        )
    if jax.config.jax_numpy_rank_promotion not in ("allow", "warn"):
        raise UsageError(
            f"JAX_NUMPY_RANK_PROMOTION={jax.config.jax_numpy_rank_promotion}: cognet-jax "
            "broadcasts arrays of different ranks; unset it (or set 'allow')"
        )
    for name in TRANSFER_GUARDS:  # JAX reads these from the environment only
        if os.environ.get(name, "").strip().lower().startswith("disallow"):
            raise UsageError(
                f"{name}={os.environ[name]}: cognet-jax moves results between host and "
                "device (values, checkpoints, progress); unset it (or set 'log')"
            )


#: ``XLA_FLAGS`` values a probe of this process found XLA to accept
_ACCEPTED_FLAGS: set[str] = set()


def check_xla_flags() -> None:
    """``UsageError`` when XLA refuses the environment's ``XLA_FLAGS`` (an unknown flag):
    XLA aborts the process that starts a backend with them, so a child process starts one
    first and its last line is the report. Nothing is started without ``XLA_FLAGS``."""
    flags = os.environ.get("XLA_FLAGS", "").strip()
    if not flags or flags in _ACCEPTED_FLAGS:  # (a process that runs several commands)
        return
    probe = [sys.executable, "-c", "import jax; jax.devices()"]
    try:
        done = subprocess.run(probe, capture_output=True, text=True, timeout=300)
    except (OSError, subprocess.TimeoutExpired):
        return  # no verdict: the command itself will tell
    if done.returncode == 0:
        _ACCEPTED_FLAGS.add(flags)
        return
    lines = [line.strip() for line in done.stderr.splitlines() if line.strip()]
    said = next((line for line in lines if "XLA_FLAGS" in line), lines[-1] if lines else "")
    said = said.split("] ", 1)[-1]  # without XLA's log prefix
    raise UsageError(f"XLA_FLAGS={flags!r}: XLA refuses it ({said})")


def backend_error(failed: BaseException | None = None) -> str | None:
    """One line when JAX cannot start a backend for its platforms (``JAX_PLATFORMS`` naming
    one this machine lacks; ``failed``: the error a command ended with, JAX's report of that),
    else ``None``."""
    import jax

    platforms = jax.config.jax_platforms or "(default)"
    if failed is not None and "Unable to initialize backend" in str(failed):
        return f"JAX could not start a backend for JAX_PLATFORMS={platforms}: {failed}"
    try:
        jax.devices()
    except Exception as err:  # JAX raises AssertionError or RuntimeError here
        detail = f": {err}" if str(err) else ""
        return f"JAX could not start a backend for JAX_PLATFORMS={platforms}{detail}"
    return None
