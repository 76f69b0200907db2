"""The ``cognet-jax`` command's arguments: one parser for every subcommand, with the flags they
share (``parser``), and an argument error as one line (``UsageError``, exit 2)."""

from __future__ import annotations

import argparse
import functools

from cognet_jax.compile_cache import CACHE_VARIABLE
from cognet_jax.errors import UsageError

#: what ``cognet-jax --help`` says first
DESCRIPTION = (
    "cognet-jax: plan decentralised POMDP controllers by cross-entropy search "
    "('cognet-jax list' names the experiments)."
)
DEFAULT_EXPERIMENT = "tagging-thesis-n3"


def _add_experiment(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "experiment",
        nargs="?",
        default=None,
        help=f"built-in experiment name or TOML file (default {DEFAULT_EXPERIMENT})",
    )


def _add_overrides(parser: argparse.ArgumentParser, help_text: str) -> None:
    """``--set SECTION.KEY=V`` (repeatable) and ``--no-progress``."""
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=V",
        help=help_text,
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def _add_checkpoints(parser: argparse.ArgumentParser, resumed: str) -> None:
    """``--checkpoint-every K`` and ``--resume DIR`` (continue ``resumed``)."""
    parser.add_argument(
        "--checkpoint-every",
        type=int,
        default=None,
        metavar="K",
        help="also write the search state every K iterations (run.checkpoint_every; "
        "run.checkpoint_seconds writes it every 60 s of search by default)",
    )
    parser.add_argument("--resume", metavar="DIR", default=None, help=f"continue {resumed}")


def _common(suffix: str = "") -> argparse.ArgumentParser:
    """The options every command takes, before or after its name: ``--debug`` and
    ``--import`` (``suffix`` tells the top-level parser's apart, ``merge_common``)."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--debug",
        dest=f"debug{suffix}",
        action="store_true",
        help="show the Python traceback of an error",
    )
    common.add_argument(
        "--import",
        dest=f"imports{suffix}",
        action="append",
        default=[],
        metavar="MODULE",
        help="import a module or .py file first, e.g. one that registers your own simulator "
        "(cognet_jax.register_env); repeatable",
    )
    common.add_argument(
        "--no-compile-cache",
        dest=f"no_compile_cache{suffix}",
        action="store_true",
        help=f"compile every program afresh (default: cache them in ${CACHE_VARIABLE}, "
        "~/.cache/cognet-jax/xla)",
    )
    return common


def merge_common(args) -> argparse.Namespace:
    """``--debug`` and ``--import`` given before the command name count as after it."""
    args.debug = args.debug or args.debug_top
    args.imports = args.imports_top + args.imports
    args.no_compile_cache = args.no_compile_cache or args.no_compile_cache_top
    return args


def _add_train(sub) -> None:
    t = sub.add_parser("train", help="run a policy search and write results, policy and plots")
    _add_experiment(t)
    t.add_argument("--seed", type=int, default=None, help="default 0")
    t.add_argument("--out", default=None, help="output folder (default runs/EXPERIMENT-seedN)")
    _add_overwrite(t)
    _add_overrides(t, "override a config field; repeatable")
    _add_checkpoints(t, "the interrupted run in DIR from its checkpoint (config and seed from it)")


def _add_overwrite(parser) -> None:
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace the run already in --out (without it such a folder is refused)",
    )


def _add_sweep(sub) -> None:
    w = sub.add_parser(
        "sweep",
        help="many seeds x settings in one compiled program; writes runs.csv/json, summary.md",
    )
    _add_experiment(w)
    w.add_argument("--seeds", type=int, default=None, help="number of seeds (default 1)")
    w.add_argument(
        "--first-seed", type=int, default=None, help="seeds are first .. first+N-1 (default 0)"
    )
    w.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="SECTION.KEY=V1,V2",
        help="values of one field to sweep; repeatable (cartesian product)",
    )
    w.add_argument("--out", default=None, help="output folder (default runs/sweep-EXPERIMENT)")
    _add_overwrite(w)
    _add_overrides(w, "override a config field for every run; repeatable")
    _add_checkpoints(w, "the interrupted sweep in DIR (experiment, seeds, grid from it)")
    w.add_argument(
        "--cpu-devices",
        type=int,
        default=None,
        metavar="N",
        help="split the CPU into N JAX devices the runs are sharded over (default: one per "
        "core, at most one per run; ignored when XLA_FLAGS sets the device count)",
    )
    w.add_argument("--coordinator", default=None, metavar="HOST:PORT", help="jax.distributed")
    w.add_argument("--num-processes", type=int, default=None, metavar="P")
    w.add_argument("--process-id", type=int, default=None, metavar="I")
    w.add_argument(
        "--cluster",
        action="store_true",
        help="initialise jax.distributed from the scheduler's environment (SLURM, ...)",
    )


def _add_evaluate(sub) -> None:
    e = sub.add_parser("evaluate", help="re-evaluate the saved best policy of a run folder")
    e.add_argument("run_dir")
    e.add_argument(
        "--rollouts", type=int, default=None, help="default: the run's evaluation.rollouts"
    )
    e.add_argument(
        "--seed",
        type=int,
        default=None,
        help="draw from this seed's evaluation key (default: the run's own seed, which "
        "reproduces its results.json final_value)",
    )
    e.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=V",
        help="change the evaluation setting (e.g. env.obs_noise=0.1)",
    )


def _add_vae(sub) -> None:
    v = sub.add_parser("vae", help="patch VAE for heatmap observations (SPEC section 6)")
    vsub = v.add_subparsers(dest="vae_command", required=True)
    vt = vsub.add_parser(
        "train", help="train the patch VAE; writes vae.msgpack, vae.json, vae_mu.png"
    )
    vt.add_argument("--out", default="runs/vae", help="output folder (default runs/vae)")
    vt.add_argument("--seed", type=int, default=0)
    vt.add_argument("--epochs", type=int, default=60)
    vt.add_argument("--latent", type=int, default=1, help="latent dimensions (default 1)")
    vt.add_argument(
        "--kl-weight", type=float, default=1.0, help="weight of the KL term (default 1)"
    )
    vt.add_argument("--no-noise", action="store_true", help="train on the 144 clean patches only")
    vt.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    vt.add_argument("--overwrite", action="store_true", help="replace a VAE already in --out")


class _ArgumentParser(argparse.ArgumentParser):
    """An argument error is one line (``UsageError``, exit 2), not usage text and a line."""

    def error(self, message: str):
        raise UsageError(f"{self.prog}: {message} (see {self.prog} --help)")


@functools.cache
def parser() -> argparse.ArgumentParser:
    """The command line's parser, built once (building it looks up argparse's translated
    messages: about 5 ms, as long as parsing a small model for ``inspect``)."""
    common = _common()
    p = _ArgumentParser(prog="cognet-jax", description=DESCRIPTION, parents=[_common("_top")])
    sub = p.add_subparsers(dest="command", required=True)
    add_parser = sub.add_parser
    sub.add_parser = lambda *a, **kw: add_parser(*a, parents=[common], **kw)  # noqa: E731
    _add_train(sub)
    _add_sweep(sub)
    _add_evaluate(sub)
    c = sub.add_parser(
        "check", help="validate an experiment and its sizes without running it (exit 0 or 2)"
    )
    _add_experiment(c)
    c.add_argument("--seed", type=int, default=0)
    _add_overrides(c, "override a config field; repeatable")
    _add_vae(sub)
    sub.add_parser("list", help="list the built-in experiments")
    i = sub.add_parser(
        "inspect", help="parse a .dpomdp file and print its sizes (or the first error in it)"
    )
    i.add_argument("file", help="a MADP .dpomdp file (.gz allowed)")
    return p
